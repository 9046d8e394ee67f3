"""Image windows, chips and measurement tables on disk (rasterio inside functions).

:class:`RasterioImage` reads windows of an image (TIFF, JPEG, JPEG 2000, ... - whatever
GDAL reads) without loading the whole image; outside the image the values are NaN.
:func:`write_chip` writes a small GeoTIFF or PNG per point and image whose pixel grid is
the image's (a GeoTIFF chip carries the transform ``column, -row`` so that it lies over
the image in a GIS that shows an image without georeferencing in pixel units).
:func:`write_table` writes the measurement template and ``image_points.csv``.
"""

from __future__ import annotations

import csv
import warnings
from pathlib import Path
from typing import Optional

import numpy as np

from vectoradjust.errors import InputFileError

__all__ = ["RasterioImage", "write_chip", "write_table", "read_pixel_table"]


class RasterioImage:
    """Windowed reading of one image (grey value: the mean of its bands).

    A tiled or uncompressed TIFF is read window by window. Any other image (a JPEG, a
    PNG, a striped compressed TIFF: formats that GDAL decodes from the first line or
    strip to reach a window) is decoded once, strip by strip, at the first read into a
    cache of grey values - a temporary file mapped into memory, removed on
    :meth:`close` - so that every later window costs a slice (milliseconds) instead of a
    decoding.

    Parameters
    ----------
    path : str or os.PathLike
    image_id : str
        For messages.
    cache : bool or None
        ``True``: always decode into the cache; ``False``: never; ``None`` (default):
        as above, by the format.
    """

    def __init__(self, path, image_id: str = "", cache: Optional[bool] = None) -> None:
        import rasterio
        import rasterio.errors

        p = Path(path)
        if not p.is_file():
            raise InputFileError(f"image {image_id!r}: file {p} does not exist",
                                 "Set path = in its [[images]] entry or give --image "
                                 f"{image_id}=FILE", path=str(p))
        try:
            with warnings.catch_warnings():  # aerial images are rarely georeferenced
                warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
                self._ds = rasterio.open(p)
        except Exception as exc:  # rasterio raises its own RasterioIOError
            raise InputFileError(f"image {image_id!r}: {p} cannot be read as a raster ({exc})",
                                 "Give a TIFF, JPEG or JPEG 2000 image", path=str(p)) from exc
        self.path = str(p)
        self.image_id = image_id
        self.size = (self._ds.width, self._ds.height)
        self.cached = _needs_cache(self._ds) if cache is None else bool(cache)
        self._cache = None
        self._cache_file = None

    def read(self, col0: int, row0: int, width: int, height: int) -> np.ndarray:
        """Grey values of the window (float, NaN outside the image)."""
        from rasterio.windows import Window

        out = np.full((height, width), np.nan)
        c0, r0 = max(col0, 0), max(row0, 0)
        c1, r1 = min(col0 + width, self.size[0]), min(row0 + height, self.size[1])
        if c1 <= c0 or r1 <= r0:
            return out
        if self.cached:
            if self._cache is None:
                self._decode()
            out[r0 - row0:r1 - row0, c0 - col0:c1 - col0] = self._cache[r0:r1, c0:c1]
            return out
        a = self._ds.read(window=Window(c0, r0, c1 - c0, r1 - r0)).astype(float)
        out[r0 - row0:r1 - row0, c0 - col0:c1 - col0] = a.mean(axis=0)
        return out

    def _decode(self, strip: int = 512) -> None:
        """Decode the whole image once, strip by strip, into the grey-value cache."""
        import tempfile

        from rasterio.windows import Window

        w, h = self.size
        self._cache_file = tempfile.TemporaryFile(prefix="vectoradjust_image_")
        cache = np.memmap(self._cache_file, dtype=np.float32, mode="w+", shape=(h, w))
        for r in range(0, h, strip):  # I/O: sequential strips, one decoding
            n = min(strip, h - r)
            cache[r:r + n] = self._ds.read(window=Window(0, r, w, n)).astype(
                np.float32).mean(axis=0)
        self._cache = cache

    def close(self) -> None:
        """Close the dataset and remove the cache."""
        self._ds.close()
        self._cache = None
        if self._cache_file is not None:
            self._cache_file.close()
            self._cache_file = None


def _needs_cache(ds) -> bool:
    """Whether windows of a dataset cost a decoding from its start: anything but a
    tiled or uncompressed GeoTIFF (JPEG, PNG, striped compressed TIFF ...)."""
    if ds.driver != "GTiff":
        return ds.driver not in ("MEM", "VRT")
    if ds.profile.get("tiled"):
        return False
    return ds.compression is not None


def write_chip(path, chip: np.ndarray, col0: int, row0: int, mark=None) -> Path:
    """Write one chip (``.tif``: GeoTIFF with a pixel-unit transform; ``.png``: 8 bit).

    ``mark`` (chip column, row) draws a small cross (PNG only) at the prediction.
    """
    import rasterio
    import rasterio.errors
    from rasterio.transform import Affine

    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    a = np.nan_to_num(np.asarray(chip, float), nan=0.0)
    if p.suffix.lower() == ".png":
        lo, hi = np.percentile(a, [1, 99]) if a.size else (0, 1)
        img = np.clip((a - lo) / max(hi - lo, 1e-9) * 255, 0, 255).astype(np.uint8)
        if mark is not None:
            c, r = int(round(mark[0])), int(round(mark[1]))
            for d in range(-4, 5):
                if 0 <= r < img.shape[0] and 0 <= c + d < img.shape[1]:
                    img[r, c + d] = 255
                if 0 <= r + d < img.shape[0] and 0 <= c < img.shape[1]:
                    img[r + d, c] = 255
        with warnings.catch_warnings():  # a PNG chip has no georeferencing
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
            with rasterio.open(p, "w", driver="PNG", width=img.shape[1], height=img.shape[0],
                               count=1, dtype="uint8") as ds:
                ds.write(img, 1)
        return p
    tr = Affine(1.0, 0.0, float(col0), 0.0, -1.0, -float(row0))
    with rasterio.open(p, "w", driver="GTiff", width=a.shape[1], height=a.shape[0], count=1,
                       dtype="float32", transform=tr) as ds:
        ds.write(a.astype(np.float32), 1)
    return p


def write_table(path, columns: dict, order: Optional[list] = None) -> Path:
    """Write a CSV of equal-length columns (floats with 6 decimals, NaN as empty)."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    names = order or list(columns)
    cols = [np.asarray(columns[k]) for k in names]
    n = len(cols[0]) if cols else 0
    with open(p, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(names)
        for i in range(n):
            w.writerow([_cell(c[i]) for c in cols])
    return p


def _cell(v) -> str:
    if isinstance(v, (float, np.floating)):
        return "" if not np.isfinite(v) else f"{float(v):.6f}"
    return str(v)


def read_pixel_table(path) -> dict:
    """Read measured pixels: ``point_id,image_id,col,row`` (more columns are ignored).

    A measurement template (``measured_col, measured_row`` columns) gives the rows whose
    ``measured_col`` is filled in; rows with an empty column are skipped.

    Raises
    ------
    InputFileError
        Missing file or columns, or a bad number (the line is named).
    """
    p = Path(path)
    if not p.is_file():
        raise InputFileError(f"{p} does not exist", "Give the CSV of measured pixels "
                             "(point_id,image_id,col,row)", path=str(p))
    with open(p, newline="", encoding="utf-8-sig") as fh:
        rows = list(csv.DictReader(fh))
    cc, rc = ("measured_col", "measured_row") if rows and "measured_col" in rows[0] \
        else ("col", "row")
    need = ("point_id", "image_id", cc, rc)
    if not rows or any(k not in rows[0] for k in need):
        raise InputFileError(f"{p}: needs the columns {', '.join(need)}",
                             "Fill col,row (pixels) of the points you measured in the "
                             "measurement template and keep its header", path=str(p))
    out: dict = {k: [] for k in ("point_id", "image_id", "col", "row", "source")}
    for i, r in enumerate(rows, start=2):
        if not (r[cc] or "").strip():
            continue
        try:
            c, w = float(r[cc]), float(r[rc])
        except ValueError:
            raise InputFileError(f"{p}, line {i}: {cc}/{rc} {r[cc]!r}, {r[rc]!r} are "
                                 "not numbers", "Write pixel coordinates as numbers",
                                 path=str(p)) from None
        out["point_id"].append(r["point_id"])
        out["image_id"].append(r["image_id"])
        out["col"].append(c)
        out["row"].append(w)
        out["source"].append((r.get("source") or "manual").strip() or "manual")
    return {k: np.asarray(v) for k, v in out.items()}

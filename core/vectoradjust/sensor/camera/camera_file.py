"""Reading a camera file: :func:`load_camera_file`, TOML text decoding with readable errors
(:func:`read_toml_text`, :func:`decode_text`, :func:`toml_error_hint`) and the
distortion table.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Callable, Union

from vectoradjust.errors import CameraError
from vectoradjust.sensor.camera.validators import _DISTORTION_META, DISTORTION_MODELS, PathLike

__all__ = ["load_camera_file", "read_toml_text", "decode_text", "toml_error_hint"]


def load_camera_file(path: PathLike) -> dict[str, Any]:
    """Read a camera TOML file into a plain dict.

    The keys may be at the top level or inside a single ``[camera]`` table. A camera
    file may not itself refer to another file (``path``).

    Raises
    ------
    CameraError
        When the file is missing, unreadable or not valid TOML.
    """
    path = Path(path)
    text = read_toml_text(
        path, f"Camera file {path}", CameraError,
        missing="Check the path (relative paths are relative to the project file)",
    )
    try:
        table = _tomllib().loads(text)
    except ValueError as exc:  # tomllib.TOMLDecodeError derives from ValueError
        raise CameraError(
            f"Camera file {path} is not valid TOML: {exc}{toml_error_hint(exc, text)}",
            "Fix the syntax at the line named",
            path=str(path),
        ) from exc
    except RecursionError:
        raise CameraError(
            f"Camera file {path} is not valid TOML: its arrays or tables are nested too deeply",
            "Check the brackets", path=str(path),
        ) from None
    if set(table) == {"camera"} and isinstance(table["camera"], Mapping):
        table = dict(table["camera"])
    if "path" in table:
        raise CameraError(
            f"Camera file {path} refers to another file (path = {table['path']!r})",
            "Put the calibration itself in the camera file; only [camera] in the project "
            "file may use path",
            path=str(path),
        )
    return table


#: larger than any project or camera file: a bigger file was given by mistake (an image)
_MAX_TOML_BYTES = 32 * 1024 * 1024
#: byte order marks other than UTF-8's, longest first
_BOMS = ((b"\xff\xfe\x00\x00", "UTF-32 (little-endian)", "UTF-32"),
         (b"\x00\x00\xfe\xff", "UTF-32 (big-endian)", "UTF-32"),
         (b"\xff\xfe", "UTF-16 (little-endian)", "UTF-16"),
         (b"\xfe\xff", "UTF-16 (big-endian)", "UTF-16"))
#: the first bytes of files that are given as a project or camera file by mistake
_MAGIC = ((b"II*\x00", "a TIFF image (GeoTIFF?)"), (b"MM\x00*", "a TIFF image (GeoTIFF?)"),
          (b"SQLite format 3\x00", "an SQLite database (a GeoPackage?)"),
          (b"PK\x03\x04", "a ZIP archive (a .zip, .kmz, .xlsx or .docx?)"),
          (b"%PDF", "a PDF document"), (b"\x89PNG", "a PNG image"),
          (b"\xff\xd8\xff", "a JPEG image"), (b"\x00\x00\x27\x0a", "a shapefile (.shp)"),
          (b"\x1f\x8b", "a gzip archive"), (b"\xd0\xcf\x11\xe0", "an old Office document"))


def read_toml_text(path: PathLike, name: str, error: type, *,
                   missing: Union[str, Callable[[], str]]) -> str:
    """The text of a TOML file (the project or a camera file), or a clear error.

    A UTF-8 byte order mark (as Windows Notepad writes it) is dropped. Anything that
    stops the file from being read is said as what it is: a missing file, a folder (with
    the ``.toml`` files in it), a permission, another encoding (named, with the line and
    the byte), a binary file (an image, a GeoPackage ...).

    Parameters
    ----------
    path : str or Path
    name : str
        How messages name the file (``"Project file 'p.toml'"``).
    error : type
        The :class:`vectoradjust.errors.VectorAdjustError` subclass to raise.
    missing : str or callable
        The mend of the message for a missing file (or a function that makes it, called
        only then).

    Returns
    -------
    str
        The text, without a byte order mark.

    Raises
    ------
    VectorAdjustError
        ``error``, naming the file and what to do.
    """
    path = Path(path)
    return decode_text(_read_bytes(path, name, error, missing), path, name, error)


def decode_text(data: bytes, path: PathLike, name: str, error: type, *,
                kind: str = "TOML files", example: str = "the TOML file (text)") -> str:
    """``data`` (a text file's bytes) as UTF-8 text, or an error naming the encoding found.

    A UTF-8 byte order mark is dropped. Another encoding (UTF-16 or UTF-32 with or
    without a byte order mark, Windows-1252, Latin-1) is an ``error`` that names it, the
    line and the byte, and how to save the file as UTF-8; NUL bytes that are no UTF-16
    make it a binary file.

    Parameters
    ----------
    data : bytes
    path : str or Path
        The file, for messages.
    name : str
        How messages name the file.
    error : type
        The :class:`vectoradjust.errors.VectorAdjustError` subclass to raise.
    kind : str
        What must be UTF-8 (``"TOML files"``, ``"CSV tables"``), for messages.
    example : str
        What to give instead of a binary file, for messages.

    Returns
    -------
    str
    """
    path = Path(path)
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        nul = data.find(b"\x00", 0, exc.start)  # the first byte that is no text
        span = (nul, nul + 1) if nul >= 0 else (exc.start, exc.end)
        raise _encoding_error(data, span, path, name, error, (kind, example)) from None
    if "\x00" in text:  # UTF-16 without a byte order mark, or a binary file
        at = data.index(b"\x00")
        raise _encoding_error(data, (at, at + 1), path, name, error, (kind, example))
    return text


def _read_bytes(path: Path, name: str, error: type, missing: Any) -> bytes:
    """The bytes of ``path`` (at most :data:`_MAX_TOML_BYTES`), or ``error``."""
    p = str(path)
    try:
        with open(path, "rb") as fh:
            data = fh.read(_MAX_TOML_BYTES + 1)
    except (FileNotFoundError, NotADirectoryError):
        raise error(f"{name} does not exist", missing if isinstance(missing, str) else missing(),
                    path=p) from None
    except IsADirectoryError:
        raise error(f"{name} is a folder, not a file", _folder_mend(path), path=p) from None
    except PermissionError:
        raise error(f"{name} cannot be read: permission denied",
                    "Give yourself read permission on the file and on the folders above it "
                    f"(chmod u+r {p!r}), or copy the project to a folder of your own",
                    path=p) from None
    except OSError as exc:
        raise error(f"{name} cannot be read ({exc.strerror or exc})", "Check the path and the "
                    "disk, or copy the file to a local folder", path=p) from None
    except ValueError:  # a NUL character in the path
        raise error(f"{name} is not a valid path (it holds a NUL character)",
                    "Give the path of the file as text", path=p.replace("\x00", "")) from None
    if len(data) > _MAX_TOML_BYTES:
        raise error(f"{name} is larger than {_MAX_TOML_BYTES // 2**20} MB: not a TOML file",
                    "Give the TOML file itself (a few kB of text), not a data file", path=p)
    for magic, what in _MAGIC:
        if data.startswith(magic):
            raise error(f"{name} is not a text file: it looks like {what}",
                        "Give the TOML file (text), not a data file", path=p)
    return data


def _folder_mend(path: Path) -> str:
    """What to give instead of the folder ``path``: the ``.toml`` files found in it."""
    try:
        found = sorted((q.name for q in path.iterdir() if q.suffix.lower() == ".toml"),
                       key=lambda n: (n.lower() != "project.toml", n))
    except OSError:
        found = []
    if len(found) == 1:
        return f"Give the .toml file inside it: {path / found[0]}"
    if found:
        shown = ", ".join(found[:10]) + (f" and {len(found) - 10} more" if len(found) > 10
                                         else "")
        return f"Give one of the .toml files inside it ({shown}), e.g. {path / found[0]}"
    return "Give the path of the .toml file itself; this folder holds no .toml file"


def _encoding_error(data: bytes, span: tuple, path: Path, name: str, error: type,
                    said: tuple = ("TOML files", "the TOML file (text)")) -> Exception:
    """The error for a file that is not UTF-8 (``data[span[0]:span[1]]`` is the first
    byte that is not), naming the encoding the file seems to be in; ``said``: what must
    be UTF-8, and what to give instead of a binary file (see :func:`decode_text`)."""
    (start, end), (kind, example) = span, said
    convert = "Save it as UTF-8 (in the editor: Save As, encoding UTF-8)"

    def iconv(codec: str) -> str:
        out = path.with_name(f"{path.stem}-utf8{path.suffix}")
        return (f"{convert}, or convert it: iconv -f {codec} -t UTF-8 {str(path)!r} > "
                f"{str(out)!r} and give that file")

    for bom, label, codec in _BOMS:
        if data.startswith(bom):
            return error(f"{name} is encoded as {label}, with a byte order mark; {kind} "
                         "must be UTF-8", iconv(codec), path=str(path),
                         details={"encoding": codec})
    line = data.count(b"\n", 0, start) + 1
    # in characters: the bytes before the first bad one are UTF-8
    column = len(data[data.rfind(b"\n", 0, start) + 1:start].decode("utf-8", "replace")) + 1
    head = data[:4096]
    if b"\x00" in head:
        even, odd = head[0::2].count(0), head[1::2].count(0)
        if max(even, odd) > 0.3 * len(head) / 2 and min(even, odd) <= 0.02 * len(head):
            codec = "UTF-16BE" if even > odd else "UTF-16LE"
            return error(f"{name} seems encoded as {codec} (UTF-16 without a byte order mark); "
                         f"{kind} must be UTF-8", iconv(codec), path=str(path),
                         details={"encoding": codec})
        return error(f"{name} is not a text file (line {line}, column {column} holds the "
                     f"byte 0x{data[start]:02X})", f"Give {example}, not a data file",
                     path=str(path))
    codec, label, short, iconv_name = (
        ("cp1252", "Windows-1252 (ANSI)", "Windows-1252", "WINDOWS-1252")
        if any(0x80 <= b <= 0x9F for b in data)
        else ("latin-1", "Latin-1 (ISO-8859-1)", "Latin-1", "LATIN1"))
    try:
        shown = f", {data[start:end].decode(codec)!r} in {short}"
    except UnicodeDecodeError:
        shown = ""
    lines = data.decode(codec, errors="replace").splitlines()
    words = lines[line - 1].strip()[:80] if line <= len(lines) else ""
    return error(f"{name} is not UTF-8 but seems encoded as {label}: line {line}, column "
                 f"{column} holds the byte 0x{data[start]:02X}{shown} (line {line}: {words!r})",
                 iconv(iconv_name), path=str(path),
                 details={"encoding": codec, "line": line, "column": column})


#: hints for TOML syntax errors users make (the error text, then what to say)
_TOML_HINTS = (
    ("escape", "a Windows path in double quotes: write it in single quotes "
               "('C:\\data\\roads.shp') or with forward slashes"),
    ("overwrite", "a key or table is written twice"),
    ("invalid value", "a text needs quotes (crs = \"EPSG:32616\"), a list brackets"),
)


def toml_error_hint(exc: Exception, text: str) -> str:
    """`` (line N: '...'; <likely cause>)`` for a TOML syntax error, or ``""``.

    Parameters
    ----------
    exc : Exception
        The :class:`tomllib.TOMLDecodeError` (its text holds ``(at line N, column M)``).
    text : str
        The file's text.
    """
    m = re.search(r"line (\d+)", str(exc))
    lines = text.splitlines()
    parts = []
    if m and 1 <= int(m.group(1)) <= len(lines):
        parts.append(f"line {m.group(1)}: {lines[int(m.group(1)) - 1].strip()[:80]!r}")
    said = str(exc).lower()
    parts += [f"perhaps {hint}" for key, hint in _TOML_HINTS if key in said]
    return f" ({'; '.join(parts)})" if parts else ""


def _tomllib():
    try:
        import tomllib  # Python >= 3.11
    except ModuleNotFoundError:  # pragma: no cover - Python < 3.11
        import tomli as tomllib
    return tomllib


def _distortion_table(
    dist: Any, where: str, source: str | None
) -> tuple[Any, Any, Any, dict[str, Any]]:
    """``distortion`` (a model name or a table) as model, convention, center, coefficients."""
    model, conv, center, coeffs = "none", "correction", None, {}
    if dist is not None:
        if isinstance(dist, str):
            model = dist
        elif isinstance(dist, Mapping):
            model = dist.get("model", "none")
            conv = dist.get("convention", "correction")
            if str(model).strip().lower() == "brown" and "convention" in dist and str(
                    conv).strip().lower() != "distortion":
                raise CameraError(
                    f"{where}: the brown model maps ideal to distorted coordinates; "
                    f"convention = {conv!r} does not apply to it",
                    "Remove convention (or write convention = \"distortion\"); give k1 k2 k3 "
                    "p1 p2 as OpenCV/OpenSfM write them",
                    path=source, details={"key": "distortion.convention"})
            center = dist.get("center")
            coeffs = {k: v for k, v in dist.items() if k not in _DISTORTION_META}
            if "model" not in dist and coeffs:
                raise CameraError(
                    f"{where}: [distortion] has coefficients but no model",
                    f"Add model = one of {', '.join(repr(m) for m in DISTORTION_MODELS)}",
                    path=source,
                    details={"key": "distortion.model"},
                )
        else:
            raise CameraError(
                f"{where}: distortion must be a table or a model name, not {dist!r}",
                'Write [camera.distortion] with model = "smac" and the coefficients',
                path=source,
            )
    return model, conv, center, coeffs


def _merge(base: Mapping[str, Any], override: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in override.items():
        if isinstance(v, Mapping) and isinstance(out.get(k), Mapping):
            merged = dict(out[k])
            merged.update(v)
            out[k] = merged
        else:
            out[k] = v
    return out

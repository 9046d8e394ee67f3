"""Reading the measurement and control CSV tables with row-precise errors.

Only the standard library and numpy: the QGIS plugin uses these readers too. The
``*_from_rows`` functions take a table that is already in memory (a header and rows of
text cells, e.g. a QGIS attribute table) and apply exactly the checks of the CSV
readers; their messages name the rows as the caller numbers them (``row 1`` = the first
feature of a layer) instead of a file's lines.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from pathlib import Path
from typing import Optional

import numpy as np

from vectoradjust.errors import CSVError, InputFileError
from vectoradjust.model import ControlPoints, Measurements
from vectoradjust.sensor.camera import decode_text
from vectoradjust.sensor.interior import FiducialMeasurements

__all__ = ["read_measurements", "read_control", "read_truth_points", "read_fiducials",
           "measurements_from_rows", "control_from_rows", "truth_from_rows", "parse_table"]

MEASUREMENT_COLUMNS = ("point_id", "image_id", "x", "y")
MEASUREMENT_OPTIONAL = ("sigma_x", "sigma_y")
FIDUCIAL_COLUMNS = ("image_id", "fiducial_id", "x", "y")
CONTROL_COLUMNS = ("point_id", "X", "Y", "Z", "sigma_x", "sigma_y", "sigma_z")
CONTROL_OPTIONAL = ("role",)
ROLES = ("control", "check")


def _read_rows(path: str) -> tuple[list[str], list[list[str]], list[int]]:
    """Header, non-blank data rows and their 1-based line numbers in the file."""
    p = Path(path)
    text = decode_text(_file_bytes(p), p, str(p), CSVError, kind="CSV tables",
                       example="the CSV table (comma-separated text)")
    reader = csv.reader(io.StringIO(text, newline=""))
    rows, numbers, done = [], [], 0
    try:
        for r in reader:
            if any(c.strip() for c in r):  # blank lines are skipped, not renumbered
                rows.append(r)
                numbers.append(reader.line_num)
            done = reader.line_num
    except csv.Error as exc:  # the row that starts after the last one read
        raise CSVError(f"{p}, line {done + 1}: cannot be read as a CSV table ({exc})",
                       "Check the quotes on that line: a quote that is not closed makes the "
                       "rest of the file one value", path=str(p),
                       details={"line": done + 1}) from exc
    if not rows:
        raise CSVError(f"{p}: the file is empty", "Add a header line and data rows", path=str(p))
    header = [h.strip() for h in rows[0]]
    return header, rows[1:], numbers[1:]


def _file_bytes(p: Path) -> bytes:
    """The bytes of a table, or an error saying what stops it being read."""
    try:
        return p.read_bytes()
    except (FileNotFoundError, NotADirectoryError):
        raise InputFileError(f"File {str(p)!r} does not exist",
                             "Check the path in the project file (relative to the project file)",
                             path=str(p)) from None
    except IsADirectoryError:
        raise InputFileError(f"{str(p)!r} is a folder, not a file",
                             "Give the path of the CSV table itself in the project file",
                             path=str(p)) from None
    except PermissionError:
        raise InputFileError(f"File {str(p)!r} cannot be read: permission denied",
                             "Give yourself read permission on it (chmod u+r) and on the "
                             "folders above it", path=str(p)) from None
    except OSError as exc:
        raise InputFileError(f"File {str(p)!r} cannot be read ({exc.strerror or exc})",
                             "Check the path and the disk", path=str(p)) from None
    except ValueError:  # a NUL character in the path
        raise InputFileError(f"File {str(p)!r} is not a valid path (it holds a NUL character)",
                             "Correct the path in the project file", path=str(p)) from None


def _fast_columns(path: str, required: Sequence[str], optional: Sequence[str] = (),
                  numeric: Sequence[str] = ()) -> Optional[dict]:
    """The columns of a plain CSV file read with pyarrow's or pandas' C parser, or None.

    The fast path of the CSV readers (the same result as :func:`_read_rows` +
    :func:`parse_table`): taken only for a well-formed file - UTF-8, no quotes, no
    blank or ragged lines (so row ``i`` is line ``i + 2``), the header as
    :func:`parse_table` wants it, every number finite and every required text filled.
    Anything else returns None and the careful reader reads the file again, naming the
    line of the first problem. None too where neither pyarrow nor pandas is installed
    (QGIS's Python).
    """
    try:
        data = Path(path).read_bytes()
    except (OSError, ValueError):  # the careful reader says what is wrong
        return None
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    if b'"' in data or b"\x00" in data or not data or data.isspace():
        return None
    raw = np.frombuffer(data, dtype=np.uint8)
    ends = np.flatnonzero(raw == ord("\n"))
    if not len(ends) or ends[-1] != len(raw) - 1:
        ends = np.append(ends, len(raw))
    before = np.searchsorted(np.flatnonzero(raw == ord(",")), ends)  # commas before each end
    per_line = np.diff(np.concatenate([[0], before]))
    try:
        header = [h.strip() for h in data[:ends[0]].decode("utf-8").rstrip("\r").split(",")]
    except UnicodeDecodeError:
        return None
    lookup = {h.lower(): h for h in header}
    known = {c.lower() for c in (*required, *optional)}
    if (len(lookup) != len(header) or any(c.lower() not in lookup for c in required)
            or any(h.lower() not in known for h in header)
            or np.any(per_line != len(header) - 1)):
        return None
    num = {lookup[c.lower()] for c in numeric if c.lower() in lookup}
    cols = _arrow_parse(data, header, num)
    if cols is None:
        cols = _pandas_parse(data, header, num)
    if cols is None or any(len(c) != len(ends) - 1 for c in cols.values()):
        return None
    out: dict = {"_line": np.arange(2, len(ends) + 1)}
    # no blank, control or non-ASCII byte but the newlines: no cell needs str.strip()
    padded = bool(np.any(((raw <= 32) & (raw != ord("\n"))) | (raw >= 128)))
    for col in (*required, *optional):
        if col.lower() not in lookup:
            continue
        arr = cols[lookup[col.lower()]]
        if col in numeric:
            if not np.all(np.isfinite(arr)):
                return None
        else:
            if padded:  # the careful reader strips every cell
                arr = np.array([c.strip() for c in arr.tolist()], dtype=object)
            if col in required and np.any(arr == ""):
                return None
        out[col] = arr
    return out


def _arrow_parse(data: bytes, header: list, numeric: set) -> Optional[dict]:
    """The columns of a checked CSV text by pyarrow's reader (C++, on every core), or
    None (pyarrow missing, or a cell it cannot read: the next reader decides).

    Numbers are float64 (an empty, ``NaN`` or ``NA`` cell is missing: None), the others
    text exactly as written (no cell is turned into a missing value).
    """
    try:
        import pyarrow as pa
        import pyarrow.csv as pcsv
    except ImportError:
        return None
    try:
        table = pcsv.read_csv(
            io.BytesIO(data),
            read_options=pcsv.ReadOptions(column_names=header, skip_rows=1),
            parse_options=pcsv.ParseOptions(quote_char=False, double_quote=False,
                                            escape_char=False, ignore_empty_lines=False),
            convert_options=pcsv.ConvertOptions(
                column_types={h: pa.float64() if h in numeric else pa.string()
                              for h in header},
                strings_can_be_null=False, quoted_strings_can_be_null=False))
    except (pa.ArrowException, ValueError, UnicodeDecodeError):
        return None
    out = {}
    for h in header:
        col = table.column(h)
        if col.null_count:
            return None
        out[h] = col.to_numpy() if h in numeric else \
            np.asarray(col.to_numpy(zero_copy_only=False), dtype=object)
    return out


def _pandas_parse(data: bytes, header: list, numeric: set) -> Optional[dict]:
    """:func:`_arrow_parse` with pandas' C parser (exact float conversion)."""
    try:
        import pandas as pd
    except ImportError:
        return None
    kw = {} if int(pd.__version__.split(".")[0]) >= 3 else {"float_precision": "round_trip"}
    try:
        frame = pd.read_csv(io.BytesIO(data), header=0, names=header, engine="c",
                            dtype={h: ("float64" if h in numeric else str) for h in header},
                            na_filter=False, skip_blank_lines=False, **kw)
    except (ValueError, UnicodeDecodeError, pd.errors.ParserError):
        return None
    return {h: frame[h].to_numpy(dtype=float if h in numeric else object) for h in header}


def parse_table(
    path: str,
    header: Sequence[str],
    rows: Sequence[Sequence[str]],
    required: Sequence[str],
    optional: Sequence[str] = (),
    numeric: Sequence[str] = (),
    allow_extra: bool = False,
    *,
    lines: Optional[Sequence[int]] = None,
    line_word: str = "line",
) -> dict[str, np.ndarray]:
    """Check the columns and convert a CSV's rows to column arrays.

    Parameters
    ----------
    path : str
        File name for messages.
    header : sequence of str
    rows : sequence of sequence of str
        Data rows (the header excluded); row ``i`` is line ``i + 2`` of the file.
    required, optional : sequence of str
        Column names (case-sensitive as in the contract; a case-insensitive match is
        accepted).
    numeric : sequence of str
        Columns converted to float; empty, non-numeric or non-finite values are errors.
    allow_extra : bool
        Whether unknown columns are allowed (ignored) or an error.
    lines : sequence of int, optional
        The number of each row in messages (default ``i + 2``: the file line of row
        ``i`` below a one-line header).
    line_word : str
        How messages call a row (``"line"`` of a file, ``"row"`` of a table).

    Returns
    -------
    dict of str to numpy.ndarray
        One array per present column (strings stripped; floats for ``numeric``), plus
        ``"_line"`` with the row numbers (``lines``).
    """
    lookup = _check_header(path, header, required, optional, allow_extra)
    ncol = len(header)
    num = (np.arange(2, len(rows) + 2) if lines is None
           else np.asarray(list(lines), dtype=np.int64).reshape(-1))
    if len(num) != len(rows):
        raise ValueError(f"{len(num)} row numbers for {len(rows)} rows")
    for i, r in enumerate(rows):
        if len(r) != ncol:
            raise CSVError(
                f"{path}, {line_word} {num[i]}: {len(r)} values where the header has {ncol} "
                "columns",
                "Give every row one value per column", path=path,
                details={line_word: int(num[i])},
            )
    out: dict[str, np.ndarray] = {"_line": num}
    for col in (*required, *optional):
        if col.lower() not in lookup:
            continue
        j = lookup[col.lower()]
        values = [r[j].strip() for r in rows]
        where = (path, line_word, num)
        out[col] = (_numeric_column(where, col, values) if col in numeric
                    else _text_column(where, col, values, col in required))
    return out


def _check_header(path: str, header: Sequence[str], required: Sequence[str],
                  optional: Sequence[str], allow_extra: bool) -> dict[str, int]:
    """The column index of each lower-cased header name; duplicate, missing or (unless
    ``allow_extra``) unknown columns are a :class:`CSVError`."""
    lookup = {h.lower(): i for i, h in enumerate(header)}
    if len(lookup) != len(header):
        dup = sorted({h for h in header if header.count(h) > 1})
        raise CSVError(f"{path}: column(s) {', '.join(dup)} appear more than once in the header",
                       "Keep each column once", path=path)
    missing = [c for c in required if c.lower() not in lookup]
    if missing:
        _other_separator(path, header)
        raise CSVError(
            f"{path}: missing column(s) {', '.join(missing)} (header is: {', '.join(header)})",
            f"The header must be {','.join(required)}"
            + (f"[,{','.join(optional)}]" if optional else ""),
            path=path, details={"missing": missing},
        )
    known = {c.lower() for c in (*required, *optional)}
    extra = [h for h in header if h.lower() not in known]
    if extra and not allow_extra:
        raise CSVError(
            f"{path}: unexpected column(s) {', '.join(extra)}",
            f"Remove them or rename them; allowed columns are {', '.join((*required, *optional))}",
            path=path, details={"extra": extra},
        )
    return lookup


def _numeric_column(where: tuple, col: str, values: list) -> np.ndarray:
    """Column ``col`` as floats; ``where`` is ``(path, line_word, row numbers)`` for the
    :class:`CSVError` of an empty, non-numeric or non-finite value."""
    path, line_word, num = where
    arr = np.empty(len(values))
    for i, v in enumerate(values):
        try:
            arr[i] = float(v)
        except ValueError:
            arr[i] = np.nan
        if not np.isfinite(arr[i]):
            raise CSVError(
                f"{path}, {line_word} {num[i]}: column {col} is {v!r}, not a finite "
                "number",
                "Enter a number (use '.' as the decimal separator)",
                path=path, details={line_word: int(num[i]), "column": col},
            )
    return arr


def _text_column(where: tuple, col: str, values: list, required: bool) -> np.ndarray:
    """Column ``col`` as an object array of stripped strings; an empty value of a
    ``required`` column is a :class:`CSVError` (``where`` as in :func:`_numeric_column`)."""
    path, line_word, num = where
    for i, v in enumerate(values):
        if required and not v:
            raise CSVError(f"{path}, {line_word} {num[i]}: column {col} is empty",
                           f"Fill in {col}", path=path,
                           details={line_word: int(num[i]), "column": col})
    return np.array(values, dtype=object)


def _other_separator(path: str, header: Sequence[str]) -> None:
    """A header in one cell that holds ``;``, a tab or ``|``: the table is not
    comma-separated (a spreadsheet's regional CSV); say so."""
    sep = next((c for c in (";", "\t", "|") if len(header) == 1 and c in header[0]), None)
    if sep:
        raise CSVError(
            f"{path}: the columns are separated by {sep!r}, not by commas (header is: "
            f"{header[0][:80]})", "Save the table as comma-separated values (in a spreadsheet: "
            "CSV UTF-8, comma delimited), with '.' as the decimal separator", path=path,
            details={"separator": sep})


def _blank_dropped(rows, lines, first: int):
    """Rows with a non-blank cell and their numbers (blank rows are skipped as in a CSV)."""
    rows = [list(r) for r in rows]
    num = list(range(first, first + len(rows))) if lines is None else [int(n) for n in lines]
    if len(num) != len(rows):
        raise ValueError(f"{len(num)} row numbers for {len(rows)} rows")
    keep = [i for i, r in enumerate(rows) if any(str(c).strip() for c in r)]
    return [rows[i] for i in keep], [num[i] for i in keep]


def read_measurements(path: str, default_sigma: Optional[float] = None,
                      unit: str = "mm") -> Measurements:
    """Read ``point_id,image_id,x,y[,sigma_x,sigma_y]`` (mm, or pixels).

    Parameters
    ----------
    path : str
    default_sigma : float, optional
        Sigma for rows without sigma columns (``[measurements] sigma``), in ``unit``.
    unit : {"mm", "pixel"}
        Unit of the coordinates and sigmas (``[measurements] unit``; pixels are
        column, row). Only used in messages: the values are returned as read and
        :func:`vectoradjust.sensor.interior.refine_measurements` converts them.

    Raises
    ------
    CSVError
        Missing/extra columns, bad numbers, non-positive sigmas, duplicate
        (point, image) pairs; the line is named.
    """
    cols = _fast_columns(path, MEASUREMENT_COLUMNS, MEASUREMENT_OPTIONAL,
                         numeric=("x", "y", "sigma_x", "sigma_y"))
    if cols is not None:
        return _measurements(cols, str(path), default_sigma, unit, "line")
    header, rows, lines = _read_rows(path)
    return measurements_from_rows(header, rows, str(path), default_sigma, unit, lines=lines)


def measurements_from_rows(header: Sequence[str], rows: Sequence[Sequence[str]], source: str,
                           default_sigma: Optional[float] = None, unit: str = "mm", *,
                           lines: Optional[Sequence[int]] = None,
                           line_word: str = "line") -> Measurements:
    """Image measurements from a table in memory, with the checks of :func:`read_measurements`.

    Parameters
    ----------
    header : sequence of str
        Column names (``point_id, image_id, x, y`` and optionally ``sigma_x, sigma_y``;
        matched case-insensitively).
    rows : sequence of sequence of str
        Data rows as text cells; rows whose cells are all blank are skipped.
    source : str
        How messages name the table (a file, ``measurements table 'name'``).
    default_sigma : float, optional
        Sigma for a table without sigma columns, in ``unit``.
    unit : {"mm", "pixel"}
        Only used in messages.
    lines : sequence of int, optional
        Number of each row in messages and in ``Measurements.rows`` (default: the
        file line, ``i + 2``).
    line_word : str
        ``"line"`` (a file) or ``"row"`` (a table).

    Returns
    -------
    Measurements
        As read (not refined), ``source`` and ``rows`` as given.

    Raises
    ------
    CSVError
        Missing/extra columns, bad numbers, non-positive sigmas, duplicate
        (point, image) pairs; the row is named.
    """
    path = source
    header = [str(h).strip() for h in header]
    rows, lines = _blank_dropped(rows, lines, 2)
    cols = parse_table(path, header, rows, MEASUREMENT_COLUMNS, MEASUREMENT_OPTIONAL,
                       numeric=("x", "y", "sigma_x", "sigma_y"), lines=lines,
                       line_word=line_word)
    return _measurements(cols, path, default_sigma, unit, line_word)


def _may_repeat(pid: np.ndarray, iid: np.ndarray) -> bool:
    """False when no (point, image) pair repeats, by hashing (pandas, linear time);
    True when one does or pandas is missing (then the sorting check decides and names
    the lines)."""
    try:
        import pandas as pd
    except ImportError:
        return True
    return bool(pd.DataFrame({"p": pid, "i": iid}, copy=False).duplicated().any())


def _measurements(cols: dict, path: str, default_sigma: Optional[float], unit: str,
                  line_word: str) -> Measurements:
    """The checks of :func:`measurements_from_rows` after :func:`parse_table`."""
    k = len(cols["_line"])
    has = ("sigma_x" in cols, "sigma_y" in cols)
    if has[0] != has[1]:
        raise CSVError(f"{path}: only one of sigma_x, sigma_y is given",
                       "Give both columns or neither", path=path)
    if has[0]:
        sigma = np.column_stack([cols["sigma_x"], cols["sigma_y"]])
    else:
        if default_sigma is None:
            raise CSVError(f"{path}: no sigma_x, sigma_y columns and no [measurements] sigma",
                           "Add sigma = 0.015 (mm) to [measurements] in the project file"
                           if unit == "mm" else
                           f"Add sigma = <{unit}s> to [measurements] in the project file",
                           path=path)
        sigma = np.full((k, 2), float(default_sigma))
    bad = np.flatnonzero(~(sigma > 0).all(axis=1))
    if bad.size:
        i = int(bad[0])
        n = int(cols["_line"][i])
        raise CSVError(f"{path}, {line_word} {n}: sigma must be positive, got "
                       f"{sigma[i].tolist()}",
                       "Enter the standard deviation of the image coordinates in "
                       + ("pixels" if unit == "pixel" else unit),
                       path=path, details={line_word: n})
    pid = cols["point_id"].astype(str)
    iid = cols["image_id"].astype(str)
    if not _may_repeat(cols["point_id"], cols["image_id"]):
        return Measurements(pid, iid, np.column_stack([cols["x"], cols["y"]]), sigma,
                            source=str(path), rows=cols["_line"])
    key = _pair_key(pid, iid)
    _, first, counts = np.unique(key, return_index=True, return_counts=True)
    if np.any(counts > 1):
        i = int(first[counts > 1][0])
        dup = cols["_line"][key == key[i]].tolist()
        p, im = str(pid[i]), str(iid[i])
        raise CSVError(
            f"{path}: point {p!r} is measured on image {im!r} more than once ({line_word}s "
            f"{', '.join(map(str, dup))})",
            "Keep one measurement per point and image", path=path,
            details={f"{line_word}s": dup, "point_id": p, "image_id": im},
        )
    return Measurements(pid, iid, np.column_stack([cols["x"], cols["y"]]), sigma,
                        source=str(path), rows=cols["_line"])


def _pair_key(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """One text per pair ``(a[i], b[i])``, equal only for equal pairs (the length of
    ``a[i]`` leads, so no character of an id can make two pairs look alike)."""
    a, b = a.astype(str), b.astype(str)
    lengths = np.char.str_len(a).astype(str) if len(a) else a
    return np.char.add(np.char.add(np.char.add(lengths, ":"), a), b)


def read_control(path: str) -> ControlPoints:
    """Read ``point_id,X,Y,Z,sigma_x,sigma_y,sigma_z[,role]`` (m).

    Raises
    ------
    CSVError
        Missing/extra columns, bad numbers, non-positive sigmas, unknown role,
        duplicate point ids; the line is named.
    """
    header, rows, lines = _read_rows(path)
    return control_from_rows(header, rows, str(path), lines=lines)


def control_from_rows(header: Sequence[str], rows: Sequence[Sequence[str]], source: str, *,
                      lines: Optional[Sequence[int]] = None,
                      line_word: str = "line") -> ControlPoints:
    """Control and check points from a table in memory, with the checks of :func:`read_control`.

    Parameters
    ----------
    header : sequence of str
        ``point_id, X, Y, Z, sigma_x, sigma_y, sigma_z`` and optionally ``role``
        (matched case-insensitively).
    rows : sequence of sequence of str
        Data rows as text cells; rows whose cells are all blank are skipped.
    source : str
        How messages name the table.
    lines : sequence of int, optional
        Number of each row in messages and in ``ControlPoints.rows`` (default ``i + 2``).
    line_word : str
        ``"line"`` (a file) or ``"row"`` (a table).

    Returns
    -------
    ControlPoints

    Raises
    ------
    CSVError
        Missing/extra columns, bad numbers, non-positive sigmas, unknown role,
        duplicate point ids; the row is named.
    """
    path = source
    header = [str(h).strip() for h in header]
    rows, lines = _blank_dropped(rows, lines, 2)
    cols = parse_table(path, header, rows, CONTROL_COLUMNS, CONTROL_OPTIONAL,
                       numeric=("X", "Y", "Z", "sigma_x", "sigma_y", "sigma_z"), lines=lines,
                       line_word=line_word)
    n = len(cols["_line"])
    sigma = np.column_stack([cols["sigma_x"], cols["sigma_y"], cols["sigma_z"]])
    bad = np.flatnonzero(~(sigma > 0).all(axis=1))
    if bad.size:
        i = int(bad[0])
        ln = int(cols["_line"][i])
        raise CSVError(f"{path}, {line_word} {ln}: sigma must be positive, got "
                       f"{sigma[i].tolist()}",
                       "Enter the survey's standard deviations in metres", path=path,
                       details={line_word: ln})
    role = cols.get("role", np.array(["control"] * n, dtype=object))
    role = np.array([r.lower() if r else "control" for r in role], dtype=object)
    badr = [i for i, r in enumerate(role) if r not in ROLES]
    if badr:
        i = badr[0]
        ln = int(cols["_line"][i])
        raise CSVError(f"{path}, {line_word} {ln}: role {str(role[i])!r} is not known",
                       "Use role = control or check", path=path, details={line_word: ln})
    pid = cols["point_id"].astype(str)
    uniq, counts = np.unique(pid, return_counts=True)
    if np.any(counts > 1):
        d = uniq[counts > 1][0]
        dup = cols["_line"][pid == d].tolist()
        raise CSVError(f"{path}: point id {str(d)!r} appears more than once ({line_word}s "
                       f"{', '.join(map(str, dup))})",
                       "Give every control and check point a unique id", path=path,
                       details={f"{line_word}s": dup, "point_id": str(d)})
    xyz = np.column_stack([cols["X"], cols["Y"], cols["Z"]])
    return ControlPoints(pid, xyz, sigma, role.astype(str), source=str(path), rows=cols["_line"])


def read_truth_points(path: str) -> tuple[np.ndarray, np.ndarray]:
    """Read a truth table ``point_id,X,Y,Z`` (simulations, validation).

    Returns
    -------
    ids : numpy.ndarray of str
    xyz : numpy.ndarray, shape (n, 3)
    """
    cols = _fast_columns(path, ("point_id", "X", "Y", "Z"), numeric=("X", "Y", "Z"))
    if cols is not None:
        return cols["point_id"].astype(str), np.column_stack([cols["X"], cols["Y"], cols["Z"]])
    header, rows, lines = _read_rows(path)
    return truth_from_rows(header, rows, str(path), lines=lines)


def truth_from_rows(header: Sequence[str], rows: Sequence[Sequence[str]], source: str, *,
                    lines: Optional[Sequence[int]] = None,
                    line_word: str = "line") -> tuple[np.ndarray, np.ndarray]:
    """A truth table ``point_id,X,Y,Z`` from a table in memory (see :func:`read_truth_points`).

    Parameters
    ----------
    header, rows, source, lines, line_word
        As for :func:`measurements_from_rows`.

    Returns
    -------
    ids : numpy.ndarray of str
    xyz : numpy.ndarray, shape (n, 3)
    """
    header = [str(h).strip() for h in header]
    rows, lines = _blank_dropped(rows, lines, 2)
    cols = parse_table(source, header, rows, ("point_id", "X", "Y", "Z"),
                       numeric=("X", "Y", "Z"), lines=lines, line_word=line_word)
    return cols["point_id"].astype(str), np.column_stack([cols["X"], cols["Y"], cols["Z"]])


def read_fiducials(path: str, unit: str = "pixel") -> FiducialMeasurements:
    """Read measured fiducials ``image_id,fiducial_id,x,y``.

    ``x, y`` are in the unit of the image measurements (``[measurements] unit``):
    pixels (``x`` = column, ``y`` = row, the row axis pointing down) or comparator mm.
    The fiducial ids are those of the camera's calibration report.

    Parameters
    ----------
    path : str
    unit : {"pixel", "mm"}
        Only used in messages.

    Returns
    -------
    FiducialMeasurements

    Raises
    ------
    CSVError
        Missing/extra columns, bad numbers, a fiducial measured twice on one image
        (the lines are named).
    """
    header, rows, lines = _read_rows(path)
    cols = parse_table(path, header, rows, FIDUCIAL_COLUMNS, numeric=("x", "y"), lines=lines)
    iid = cols["image_id"].astype(str)
    fid = cols["fiducial_id"].astype(str)
    key = _pair_key(iid, fid)
    _, first, counts = np.unique(key, return_index=True, return_counts=True)
    if np.any(counts > 1):
        i = int(first[counts > 1][0])
        lines = cols["_line"][key == key[i]].tolist()
        im, f = str(iid[i]), str(fid[i])
        raise CSVError(
            f"{path}: fiducial {f!r} is measured on image {im!r} more than once (lines "
            f"{', '.join(map(str, lines))})",
            f"Keep one measurement ({unit}) per fiducial and image", path=path,
            details={"lines": lines, "image_id": im, "fiducial_id": f},
        )
    return FiducialMeasurements(iid, fid, np.column_stack([cols["x"], cols["y"]]),
                                source=str(path), rows=cols["_line"])

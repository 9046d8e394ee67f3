"""The fast CSV path (pyarrow's reader, else pandas' C parser) reads exactly what the
careful reader reads, and hands every irregular file to the careful reader, whose
messages name the line. Every test runs with each of the two parsers."""

from __future__ import annotations

import csv

import numpy as np
import pytest

pytest.importorskip("pandas")

from vectoradjust.errors import CSVError  # noqa: E402
from vectoradjust.files import csv_tables as tables  # noqa: E402


@pytest.fixture(autouse=True, params=["pyarrow", "pandas"])
def engine(request, monkeypatch):
    """The parser of the fast path: pyarrow (pandas must then not be asked), or pandas
    (as where pyarrow is not installed)."""
    if request.param == "pandas":
        monkeypatch.setattr(tables, "_arrow_parse", lambda *args: None)
    else:
        pytest.importorskip("pyarrow")
        real = tables._pandas_parse

        def only_after_a_refusal(data, header, numeric):  # pyarrow refused a cell
            assert pyarrow_refused, "pandas parsed a file pyarrow should have read"
            return real(data, header, numeric)

        pyarrow_refused = []
        arrow = tables._arrow_parse

        def spy(data, header, numeric):
            out = arrow(data, header, numeric)
            if out is None:
                pyarrow_refused.append(True)
            return out

        monkeypatch.setattr(tables, "_arrow_parse", spy)
        monkeypatch.setattr(tables, "_pandas_parse", only_after_a_refusal)
    return request.param


def _write(path, text):
    path.write_bytes(text.encode("utf-8"))
    return path


def _careful(path, default_sigma=None):
    with open(path, newline="", encoding="utf-8-sig") as fh:
        rows = list(csv.reader(fh))
    return tables.measurements_from_rows(rows[0], rows[1:], str(path), default_sigma)


def _measurement_text(n, rng, sigma=True, newline="\n"):
    head = "point_id, image_id ,x,y" + (",sigma_x,sigma_y" if sigma else "")
    lines = [head]
    for i in range(n):
        x, y = rng.normal(0, 80, 2) * 10.0 ** rng.integers(-6, 3)
        row = [f" p{i} ", "L" if i % 2 else "R", repr(float(x)), f"{y:.17g}"]
        if sigma:
            row += [f"{0.01 + rng.random() * 0.01!r}", "1.5e-2"]
        lines.append(",".join(row))
    return newline.join(lines) + newline


@pytest.mark.parametrize("newline", ["\n", "\r\n"])
@pytest.mark.parametrize("sigma", [True, False])
def test_fast_path_equals_the_careful_reader(tmp_path, newline, sigma):
    rng = np.random.default_rng(5)
    p = _write(tmp_path / "m.csv", "\ufeff" + _measurement_text(500, rng, sigma, newline))
    assert tables._fast_columns(str(p), tables.MEASUREMENT_COLUMNS,
                                tables.MEASUREMENT_OPTIONAL, ("x", "y")) is not None
    fast = tables.read_measurements(str(p), default_sigma=0.015)
    slow = _careful(p, default_sigma=0.015)
    assert fast.point_id.tolist() == slow.point_id.tolist()
    assert fast.image_id.tolist() == slow.image_id.tolist()
    assert np.array_equal(fast.xy, slow.xy) and np.array_equal(fast.sigma, slow.sigma)
    assert np.array_equal(fast.rows, slow.rows) and fast.rows[0] == 2


@pytest.mark.parametrize("text, line", [
    ("point_id,image_id,x,y\na,L,1,2\n\nb,L,1,2x\n", 4),  # blank line: numbering kept
    ("point_id,image_id,x,y\na,L,1,2\nb,L,nan,2\n", 3),  # not finite
    ("point_id,image_id,x,y\na,L,1,2\nb,L,,2\n", 3),  # empty number
    ('point_id,image_id,x,y\n"a",L,1,2\nb,L,1,q\n', 3),  # quotes: the careful reader
    ("point_id,image_id,x,y\na,L,1,2\nb,L,1\n", 3),  # ragged
    ("point_id,image_id,x,y\na,L,1,2\n ,L,1,2\n", 3),  # empty id
])
def test_irregular_files_get_the_careful_readers_messages(tmp_path, text, line):
    p = _write(tmp_path / "m.csv", text)
    assert tables._fast_columns(str(p), tables.MEASUREMENT_COLUMNS,
                                tables.MEASUREMENT_OPTIONAL, ("x", "y")) is None
    with pytest.raises(CSVError, match=f"line {line}"):
        tables.read_measurements(str(p), default_sigma=0.01)


def test_duplicates_and_bad_sigma_are_found_on_the_fast_path(tmp_path):
    p = _write(tmp_path / "m.csv", "point_id,image_id,x,y\na,L,1,2\nb,L,1,2\na,L,3,4\n")
    with pytest.raises(CSVError, match="lines 2, 4"):
        tables.read_measurements(str(p), default_sigma=0.01)
    q = _write(tmp_path / "s.csv", "point_id,image_id,x,y,sigma_x,sigma_y\na,L,1,2,0.1,0\n")
    with pytest.raises(CSVError, match="line 2: sigma must be positive"):
        tables.read_measurements(str(q))


def test_truth_points_fast_and_careful_agree(tmp_path):
    rng = np.random.default_rng(2)
    xyz = rng.normal(5e5, 1e3, (300, 3))
    text = "point_id,X,Y,Z\n" + "".join(f"v{i},{float(x)!r},{float(y)!r},{float(z)!r}\n"
                                        for i, (x, y, z) in enumerate(xyz))
    p = _write(tmp_path / "t.csv", text)
    ids, got = tables.read_truth_points(str(p))
    assert ids.tolist() == [f"v{i}" for i in range(300)] and np.array_equal(got, xyz)
    lines = text.splitlines(keepends=True)
    lines[8] = "v7,abc,1,2\n"  # point v7 is on line 9
    _write(p, "".join(lines))
    with pytest.raises(CSVError, match="line 9"):
        tables.read_truth_points(str(p))


def test_unicode_blanks_are_stripped_as_by_the_careful_reader(tmp_path):
    p = _write(tmp_path / "m.csv", "point_id,image_id,x,y\n\u00a0a\u2003,L,1,2\nb,R\u00a0,3,4\n")
    fast = tables.read_measurements(str(p), default_sigma=0.01)
    assert fast.point_id.tolist() == ["a", "b"] and fast.image_id.tolist() == ["L", "R"]
    assert fast.point_id.tolist() == _careful(p, 0.01).point_id.tolist()


def test_ids_that_look_like_numbers_stay_text(tmp_path, engine):
    p = _write(tmp_path / "m.csv", "point_id,image_id,x,y\n007,1,1,2\n1e3,2,3,4\nNA,1,5,6\n")
    fast = tables._fast_columns(str(p), tables.MEASUREMENT_COLUMNS,
                                tables.MEASUREMENT_OPTIONAL, ("x", "y"))
    assert fast is not None, engine
    assert fast["point_id"].tolist() == ["007", "1e3", "NA"]
    assert fast["image_id"].tolist() == ["1", "2", "1"]
    m = tables.read_measurements(str(p), default_sigma=0.01)
    assert m.point_id.tolist() == _careful(p, 0.01).point_id.tolist()

"""The small-image measurement sample (``resources/sample/measure``, issue 28).

A newcomer's two commands - ``measure predict`` and ``measure transfer`` - run on the
sample as shipped (a copy, so that ``out/`` is not written into ``resources``) and their
results are compared with the truth the generator wrote (``truth_pixels.csv``); the
generator reproduces the shipped tables and images; the README's table of the
measurement options names every flag of both commands with its default.
"""

from __future__ import annotations

import csv
import re
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from vectoradjust.cli import main

pytestmark = pytest.mark.io  # reads and writes JPEG images, GeoTIFF and shapefiles

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "resources" / "sample" / "measure"


def _rows(path: Path) -> list:
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def _readme_commands() -> list:
    """The newcomer's commands of README's "Try it on the sample" (``vectoradjust ...``)."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    block = text.split("**Try it on the sample.**", 1)[1].split("```", 2)[1]
    return [ln.split()[1:] for ln in block.splitlines() if ln.startswith("vectoradjust ")]


@pytest.fixture(scope="module")
def ran(tmp_path_factory):
    """The sample copied (as ``msample``) and README's two commands run on it."""
    d = tmp_path_factory.mktemp("copy") / "msample"
    shutil.copytree(SAMPLE, d, ignore=shutil.ignore_patterns("out", "__pycache__"))
    commands = _readme_commands()
    assert [c[:2] for c in commands] == [["measure", "predict"], ["measure", "transfer"]]
    for words in commands:
        argv = [str(d.parent / w) if w.startswith("msample/") else w for w in words]
        assert main([*argv, "-q"]) == 0, argv
    return d


def test_sample_is_small():
    size = sum(p.stat().st_size for p in SAMPLE.rglob("*") if p.is_file())
    assert size < 300_000, size
    whole = sum(p.stat().st_size for p in (ROOT / "resources").rglob("*") if p.is_file()
                and "__pycache__" not in p.parts)
    assert whole < 3_000_000, whole


def test_predict_on_the_sample(ran):
    tab = _rows(ran / "out" / "measurement_template.csv")
    truth = {(r["point_id"], r["image_id"]): (float(r["col"]), float(r["row"]))
             for r in _rows(ran / "truth_pixels.csv")}
    pred = {(r["point_id"], r["image_id"]): r for r in tab}
    assert set(truth) <= set(pred)  # every control point on every image it falls on
    # the windows (approximate orientation: 0.5 m, 0.02 deg) hold the true pixels
    inside = []
    for k, (c, r) in truth.items():
        p = pred[k]
        a, b = float(p["win_major"]), float(p["win_minor"])
        t = np.radians(float(p["win_angle"]))
        d = np.array([c - float(p["col"]), r - float(p["row"])])
        u = np.array([np.cos(t), np.sin(t)]) @ d, np.array([-np.sin(t), np.cos(t)]) @ d
        inside.append((u[0] / a) ** 2 + (u[1] / b) ** 2 <= 1.0)
    assert all(inside), inside
    assert all(float(p["win_major"]) < 20 for p in tab if p["kind"] == "control")
    auto = _rows(ran / "out" / "automatic_points.csv")
    assert sum(r["accepted"] == "True" for r in auto) >= 5  # road junctions located


def test_transfer_on_the_sample(ran):
    """At least 75 % of the transfers to points with a truth accepted, none farther than
    1 px from the true pixel and the median within 0.4 px (the reference measurements
    on L carry 0.2 px of noise per axis, which every transfer inherits)."""
    truth = {(r["point_id"], r["image_id"]): (float(r["col"]), float(r["row"]))
             for r in _rows(ran / "truth_pixels.csv")}
    rows = [r for r in _rows(ran / "out" / "transfer.csv")
            if (r["point_id"], r["image_id"]) in truth]
    assert len(rows) >= 20 and {r["image_id"] for r in rows} == {"M", "R"}
    acc = [r for r in rows if r["accepted"] == "True"]
    assert len(acc) >= 0.75 * len(rows), (len(acc), len(rows))
    err = np.array([np.hypot(float(r["col"]) - truth[r["point_id"], r["image_id"]][0],
                             float(r["row"]) - truth[r["point_id"], r["image_id"]][1])
                    for r in acc])
    assert err.max() < 1.0 and np.median(err) < 0.4, err
    quality = _rows(ran / "out" / "image_points_quality.csv")
    assert {r["source"] for r in quality} == {"manual", "transferred", "automatic"}
    assert (ran / "out" / "image_points.csv").read_text().splitlines()[0] == \
        "point_id,image_id,x,y,sigma_x,sigma_y"


def test_the_generator_reproduces_the_sample(tmp_path):
    import importlib.util

    spec = importlib.util.spec_from_file_location("make_sample", SAMPLE / "make_sample.py")
    make_sample = importlib.util.module_from_spec(spec)
    before, sys.dont_write_bytecode = sys.dont_write_bytecode, True  # no __pycache__ in
    try:  # resources/
        spec.loader.exec_module(make_sample)
    finally:
        sys.dont_write_bytecode = before
    make_sample.main(tmp_path)
    for name in ("project.toml", "gcps.csv", "measured_L.csv", "truth_pixels.csv",
                 "truth_eo.csv"):
        assert (tmp_path / name).read_text() == (SAMPLE / name).read_text(), name
    import warnings

    import rasterio

    for iid in "LMR":  # decoded grey values (the JPEG bytes depend on libjpeg)
        with warnings.catch_warnings():  # the images have no georeferencing
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
            with rasterio.open(tmp_path / f"{iid}.jpg") as a, \
                    rasterio.open(SAMPLE / f"{iid}.jpg") as b:
                diff = np.abs(a.read(1).astype(int) - b.read(1).astype(int))
        assert diff.mean() < 0.5 and diff.max() <= 8, (iid, diff.mean(), diff.max())


def _readme_options() -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    return text.split("### Options of measure predict and measure transfer", 1)[1].split(
        "\n#", 1)[0]


def test_the_readme_lists_every_measure_option_with_its_default():
    """Every flag of ``measure predict`` / ``transfer`` in README's option table, the
    transfer's matching flags in the order of MatchSettings, each with the parser's
    default."""
    import argparse

    from vectoradjust.cli.commands import build_parser

    table = _readme_options()
    rows = {}
    for line in table.splitlines():
        m = re.match(r"\| (`[^|]*`) \| ([^|]*) \|", line)
        if m:
            for flag in re.findall(r"--[\w-]+", m.group(1)):
                rows[flag] = m.group(2).strip()
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    msub = next(a for a in sub.choices["measure"]._actions
                if isinstance(a, argparse._SubParsersAction))
    order = []
    for name in ("predict", "transfer"):
        for a in msub.choices[name]._actions:
            long = [s for s in a.option_strings if s.startswith("--")]
            if not long or long[0] == "--help":
                continue
            assert long[0] in rows, f"README: measure {name} {long[0]} missing"
            want = "" if a.default in (None, False, [], argparse.SUPPRESS) else str(a.default)
            if isinstance(a.default, bool) and a.default:
                want = "on"
            assert rows[long[0]].strip("`") == want, (long[0], rows[long[0]], want)
            if long[0] not in order:  # the options both commands have: listed once
                order.append(long[0])
    listed = [f for f in rows if f in order]
    pos = [listed.index(f) for f in order if f in listed]
    assert pos == sorted(pos), "README's order differs from the parser's"

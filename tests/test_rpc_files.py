"""RPC files (files/rpc.py): reading, writing, GDAL's side files, and the CRS ground frame.

Reading is checked against rasterio (GDAL) on the real QuickBird-2 image and on small
synthetic rasters whose RPCs GDAL itself wrote (GeoTIFF tags, ``_RPC.TXT``, ``.RPB``,
NITF RPC00B); writing by reading back with rasterio. :func:`crs_frame` is checked
against pyproj, and its refusals (geographic CRS, missing geoid grid) by their messages.
"""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import numpy as np
import pytest

from vectoradjust.errors import CRSError, InputFileError
from vectoradjust.files.rpc import (
    crs_frame,
    read_rpc,
    rpc_side_file,
    utm_crs,
    write_rpc,
    write_rpc_geotiff,
)
from vectoradjust.sensor.rpc import RpcModel

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "rpc"
QB = DATA / "quickbird2" / "qb2_basic1b.tif"
_FIELDS = ("line_off", "samp_off", "lat_off", "long_off", "height_off", "line_scale",
           "samp_scale", "lat_scale", "long_scale", "height_scale")
_POLYS = ("line_num", "line_den", "samp_num", "samp_den")


def _quickbird() -> Path:
    if not QB.is_file():
        pytest.skip(f"real RPC data not found: {QB} (see /work/shared/data/rpc/README.md)")
    return QB


def _rasterio():
    rasterio = pytest.importorskip("rasterio")
    warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
    return rasterio


def _gdal_rpc(path) -> RpcModel:
    """The RPCs as rasterio parses them (its own RPC class)."""
    rasterio = _rasterio()
    with rasterio.open(path) as src:
        assert src.rpcs is not None, f"GDAL finds no RPCs for {path}"
        return RpcModel.from_gdal(src.rpcs.to_gdal(), source=str(path))


def _toy_rpc(**changes) -> RpcModel:
    """A model with coefficients that use every digit (17 significant)."""
    rng = np.random.default_rng(11)
    polys = {p: rng.normal(0.0, 1e-3, 20) for p in _POLYS}
    polys["line_num"][2], polys["samp_num"][1] = -1.0123456789012345, 1.0098765432109876
    polys["line_den"][0] = polys["samp_den"][0] = 1.0
    base = dict(line_off=399.45123456789012, samp_off=637.0512345678901, lat_off=-33.6726,
                long_off=24.4057, height_off=703.0, line_scale=1210.0, samp_scale=1377.6,
                lat_scale=0.0737, long_scale=0.0995, height_scale=501.0, err_bias=12.15,
                err_rand=0.3, **polys)
    base.update(changes)
    return RpcModel(**base)


def _close(a: RpcModel, b: RpcModel, rtol: float = 0.0) -> None:
    for f in _FIELDS:
        assert getattr(a, f) == pytest.approx(getattr(b, f), rel=rtol, abs=0.0), f
    for p in _POLYS:
        np.testing.assert_allclose(getattr(a, p), getattr(b, p), rtol=rtol, atol=0.0, err_msg=p)


def _plain_tif(path: Path, rpc: RpcModel = None, **options) -> Path:
    """A 20 x 10 uint8 GeoTIFF, with ``rpc`` in its tags when given."""
    rasterio = _rasterio()
    from rasterio.rpc import RPC

    kw = dict(driver="GTiff", width=20, height=10, count=1, dtype="uint8", **options)
    if rpc is not None:
        kw["rpcs"] = RPC.from_gdal(rpc.to_gdal())
    with rasterio.open(path, "w", **kw) as dst:
        dst.write(np.arange(200, dtype="uint8").reshape(1, 10, 20))
    return path


# ---------------------------------------------------------------------- reading
@pytest.mark.io
def test_read_rpc_quickbird_equals_rasterio_and_projects_like_gdal():
    path = _quickbird()
    rpc = read_rpc(path)
    assert rpc == _gdal_rpc(path)                     # every number exactly
    assert rpc.source == str(path)
    assert (rpc.line_off, rpc.samp_off, rpc.lat_off, rpc.long_off) == (
        399.45, 637.05, -33.6726, 24.4057)
    assert (rpc.err_bias, rpc.err_rand) == (12.15, 0.3)
    # the model read projects as GDAL's RPC transformer does (corner convention)
    rasterio = _rasterio()
    from rasterio.transform import RPCTransformer

    rng = np.random.default_rng(1)
    lon = rpc.long_off + rpc.long_scale * rng.uniform(-0.9, 0.9, 200)
    lat = rpc.lat_off + rpc.lat_scale * rng.uniform(-0.9, 0.9, 200)
    h = rpc.height_off + rpc.height_scale * rng.uniform(-0.9, 0.9, 200)
    with rasterio.open(path) as src, RPCTransformer(src.rpcs) as t:
        rows, cols = t.rowcol(lon, lat, zs=h, op=np.positive)
    ours = rpc.project(lon, lat, h)
    assert np.abs(ours - np.column_stack([cols, rows])).max() < 1e-6   # px


@pytest.mark.io
def test_read_rpc_missing_unreadable_and_without_rpcs(tmp_path):
    missing = tmp_path / "nothere.tif"
    with pytest.raises(InputFileError, match="nothere.tif: does not exist") as err:
        read_rpc(missing)
    assert err.value.path == str(missing) and "_rpc.txt" in err.value.mend
    bad = tmp_path / "bad.tif"
    bad.write_bytes(b"this is not an image")
    with pytest.raises(InputFileError, match="bad.tif: cannot be read as an image"):
        read_rpc(bad)
    plain = _plain_tif(tmp_path / "plain.tif")
    with pytest.raises(InputFileError, match="plain.tif: the image has no RPCs") as err:
        read_rpc(plain)
    assert "plain_rpc.txt or plain.RPB next to it" in str(err.value)
    assert "side file" in err.value.mend
    with pytest.raises(InputFileError, match="is a directory"):
        read_rpc(tmp_path)


@pytest.mark.io
def test_read_rpc_finds_gdal_side_files_and_reads_them_directly(tmp_path):
    rpc = _toy_rpc()
    # GDAL writes the side files itself: _RPC.TXT (RPCTXT=YES) and .RPB (baseline TIFF)
    txt_img = _plain_tif(tmp_path / "a.tif", rpc, RPCTXT="YES")
    rpb_img = _plain_tif(tmp_path / "b.tif", rpc, PROFILE="BASELINE")
    txt, rpb = tmp_path / "a_RPC.TXT", tmp_path / "b.RPB"
    assert txt.is_file() and rpb.is_file()
    for image, side in ((txt_img, txt), (rpb_img, rpb)):
        via_gdal = read_rpc(image)
        assert via_gdal.source == str(side)                 # named after the side file
        direct = read_rpc(side)                             # parsed here
        assert direct.source == str(side)
        _close(via_gdal, _gdal_rpc(image))
        _close(direct, via_gdal)
        _close(direct, rpc, rtol=1e-14)                     # GDAL keeps 15 digits
        assert (direct.err_bias, direct.err_rand) == (12.15, 0.3)


@pytest.mark.io
def test_read_rpc_nitf_rpc00b(tmp_path):
    rasterio = _rasterio()
    shutil = pytest.importorskip("rasterio.shutil")

    rpc = _toy_rpc()
    ntf = tmp_path / "img.ntf"
    shutil.copy(_plain_tif(tmp_path / "src.tif", rpc), ntf, driver="NITF")
    for aux in tmp_path.glob("img.ntf.aux.xml"):   # keep only the RPC00B TRE
        aux.unlink()
    with rasterio.open(ntf) as src:
        assert "RPC00B" in src.tags(ns="TRE")
    got = read_rpc(ntf)
    assert got.source == str(ntf)
    _close(got, _gdal_rpc(ntf))
    # RPC00B's fixed fields: offsets and image scales as integers, 7 significant digits
    assert (got.line_off, got.samp_off, got.samp_scale) == (399.0, 637.0, 1378.0)
    for p in _POLYS:
        np.testing.assert_allclose(getattr(got, p), getattr(rpc, p), rtol=5e-7, atol=5e-13)


@pytest.mark.io
def test_read_rpc_txt_with_units_and_its_errors(tmp_path):
    good = tmp_path / "scene_rpc.txt"
    text = write_rpc(_toy_rpc(), good).read_text()
    line_off = f"LINE_OFF: {399.45123456789012!r}"      # every digit (repr)
    assert text.splitlines()[:3] == ["ERR_BIAS: 12.15", "ERR_RAND: 0.3", line_off]
    # GeoEye / Ikonos style: signs, leading zeros, units after the values
    vendor = tmp_path / "vendor_RPC.TXT"
    vendor.write_text(text.replace(line_off, "LINE_OFF: +000399.45 pixels")
                      .replace("LAT_OFF: -33.6726", "LAT_OFF: -33.67260000 degrees")
                      .replace("HEIGHT_OFF: 703.0", "HEIGHT_OFF: +0703.000 meters"))
    got = read_rpc(vendor)
    assert (got.line_off, got.lat_off, got.height_off) == (399.45, -33.6726, 703.0)
    short = tmp_path / "short_rpc.txt"
    short.write_text(text.replace("SAMP_DEN_COEFF_17:", "SAMP_DEN_COEFF_X:"))
    with pytest.raises(InputFileError, match="short_rpc.txt: the RPC file lacks "
                                             "SAMP_DEN_COEFF_17") as err:
        read_rpc(short)
    assert err.value.details["key"] == "SAMP_DEN_COEFF_17"
    bad = tmp_path / "bad_rpc.txt"
    bad.write_text(text.replace("LAT_SCALE: 0.0737", "LAT_SCALE: abc"))
    with pytest.raises(InputFileError, match=r"bad_rpc.txt: RPC LAT_SCALE is not a number"):
        read_rpc(bad)
    nolines = tmp_path / "empty_rpc.txt"
    nolines.write_text("")
    with pytest.raises(InputFileError, match="empty_rpc.txt: the RPC file lacks"):
        read_rpc(nolines)
    rpb = tmp_path / "x.RPB"
    rpb.write_text('satId = "QB02";\nBEGIN_GROUP = IMAGE\n\tlineOffset = 1.0;\nEND_GROUP = IMAGE\n')
    with pytest.raises(InputFileError, match="x.RPB: the RPB file lacks sampOffset"):
        read_rpc(rpb)


# ---------------------------------------------------------------------- writing
@pytest.mark.io
def test_write_rpc_side_file_is_read_back_by_gdal(tmp_path):
    rpc = _toy_rpc(err_bias=None, err_rand=None)
    image = _plain_tif(tmp_path / "scene.v2.tif")
    side = write_rpc(rpc, image)
    assert side == tmp_path / "scene.v2_rpc.txt" == rpc_side_file(image)
    assert "ERR_BIAS" not in side.read_text()
    assert read_rpc(image) == rpc                       # through GDAL: every digit
    assert _gdal_rpc(image) == rpc                      # rasterio's own parsing
    assert read_rpc(side) == rpc                        # parsed here
    assert read_rpc(image).source == str(side)
    assert write_rpc(rpc, tmp_path / "other_RPC.TXT") == tmp_path / "other_RPC.TXT"
    with pytest.raises(InputFileError, match="Cannot write the RPC file"):
        write_rpc(rpc, tmp_path / "no" / "dir" / "x.tif")


@pytest.mark.io
def test_a_side_file_overrides_the_tags(tmp_path):
    # GDAL 3.10 takes a side file's RPCs before the image's own tags: write_rpc can
    # correct an image without rewriting it, and write_rpc_geotiff refuses such a name
    tagged = _plain_tif(tmp_path / "t.tif", _toy_rpc())
    corrected = _toy_rpc(samp_off=640.0)
    assert read_rpc(tagged).samp_off != 640.0
    write_rpc(corrected, tagged)
    assert read_rpc(tagged) == corrected
    with pytest.raises(InputFileError, match="t_rpc.txt lies next to it"):
        write_rpc_geotiff(_plain_tif(tmp_path / "src.tif"), corrected, tagged)


@pytest.mark.io
def test_write_rpc_geotiff_quickbird_round_trip(tmp_path):
    rasterio = _rasterio()
    path = _quickbird()
    corrected = dataclasses.replace(read_rpc(path), samp_off=640.0512345678901,
                                    line_off=401.5498765432101)
    dst = write_rpc_geotiff(path, corrected, tmp_path / "qb_corrected.tif")
    assert dst == tmp_path / "qb_corrected.tif"
    got = read_rpc(dst)
    _close(got, corrected, rtol=1e-14)               # GDAL's 15 significant digits
    assert got.samp_off == pytest.approx(640.0512345678901, abs=1e-12)
    assert (got.err_bias, got.err_rand) == (12.15, 0.3)
    with rasterio.open(path) as a, rasterio.open(dst) as b:
        assert b.profile["compress"] == a.profile["compress"] == "jpeg"
        np.testing.assert_array_equal(a.read(), b.read())   # pixels untouched
        assert b.files == [str(dst)]
    assert read_rpc(path) == _gdal_rpc(path)          # the source is unchanged
    with pytest.raises(InputFileError, match="would overwrite the source"):
        write_rpc_geotiff(dst, corrected, dst)
    with pytest.raises(InputFileError, match="does not exist"):
        write_rpc_geotiff(tmp_path / "none.tif", corrected, tmp_path / "x.tif")


@pytest.mark.io
def test_write_rpc_geotiff_from_a_synthetic_nitf(tmp_path):
    rasterio = _rasterio()
    shutil = pytest.importorskip("rasterio.shutil")

    ntf = tmp_path / "img.ntf"
    shutil.copy(_plain_tif(tmp_path / "src.tif", _toy_rpc()), ntf, driver="NITF")
    corrected = _toy_rpc(samp_off=700.25)
    dst = write_rpc_geotiff(ntf, corrected, tmp_path / "img.tif")
    _close(read_rpc(dst), corrected, rtol=1e-14)
    with rasterio.open(ntf) as a, rasterio.open(dst) as b:
        assert b.driver == "GTiff"
        np.testing.assert_array_equal(a.read(), b.read())


# ---------------------------------------------------------------------- ground frame
def _pyproj():
    return pytest.importorskip("pyproj")


def test_crs_frame_utm_ellipsoidal_matches_pyproj():
    pyproj = _pyproj()
    frame = crs_frame("EPSG:32735")
    assert frame.description.startswith("WGS 84 / UTM zone 35S, ellipsoidal heights -> WGS 84")
    rng = np.random.default_rng(3)
    xyz = np.column_stack([rng.uniform(2.4e5, 3.6e5, 100), rng.uniform(6.21e6, 6.33e6, 100),
                           rng.uniform(0, 1500, 100)])
    llh, jac = frame.to_geodetic(xyz)
    t = pyproj.Transformer.from_crs("EPSG:32735", "EPSG:4326", always_xy=True)
    lon, lat = t.transform(xyz[:, 0], xyz[:, 1])
    np.testing.assert_allclose(llh[:, 0], lon, rtol=0, atol=1e-12)
    np.testing.assert_allclose(llh[:, 1], lat, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(llh[:, 2], xyz[:, 2])       # WGS 84: h unchanged
    assert jac.shape == (100, 3, 3)
    np.testing.assert_allclose(frame.from_geodetic(llh), xyz, rtol=0, atol=1e-6)
    with pytest.raises(CRSError, match="cannot be transformed from EPSG:32735"):
        frame.to_geodetic([[np.inf, 6.27e6, 0.0]])


def test_crs_frame_refuses_geographic_and_non_metric_crs():
    _pyproj()
    with pytest.raises(CRSError, match="geographic") as err:
        crs_frame("EPSG:4326", near=(24.41, -33.67))
    assert "the UTM zone of the data is EPSG:32735" in err.value.mend
    with pytest.raises(CRSError, match="geographic") as err:
        crs_frame("EPSG:4979")
    assert "UTM zone" in err.value.mend
    with pytest.raises(CRSError, match="US survey foot"):
        crs_frame("EPSG:2229")
    with pytest.raises(CRSError, match="not a projected CRS"):
        crs_frame("EPSG:4978")
    with pytest.raises(CRSError, match="not understood"):
        crs_frame("EPSG:no")


def test_utm_crs_zones():
    assert utm_crs(24.41, -33.67) == "EPSG:32735"
    assert utm_crs(-87.6, 41.9) == "EPSG:32616"
    assert utm_crs(5.3, 60.4) == "EPSG:32632"         # south-west Norway
    assert utm_crs(10.0, 78.0) == "EPSG:32633"        # Svalbard
    assert utm_crs(179.99, -10.0) == "EPSG:32760"
    assert utm_crs(0.0, 85.0) == "EPSG:5041"


def test_crs_frame_heights_options_must_agree():
    _pyproj()
    with pytest.raises(CRSError, match="has orthometric heights"):
        crs_frame("EPSG:32735+5773")
    with pytest.raises(CRSError, match="needs the geoid"):
        crs_frame("EPSG:32735", heights="orthometric")
    with pytest.raises(CRSError, match="with heights='ellipsoidal'"):
        crs_frame("EPSG:32735", geoid="EGM96")
    with pytest.raises(CRSError, match="not known"):
        crs_frame("EPSG:32735", heights="geoid")
    with pytest.raises(CRSError, match="not a vertical CRS"):
        crs_frame("EPSG:32735", heights="orthometric", geoid="EPSG:4326")
    with pytest.raises(CRSError, match="not in EGM2008"):
        crs_frame("EPSG:32735+5773", heights="orthometric", geoid="EGM2008")


#: the older names under which distributions ship PROJ's grids (Debian's proj-data:
#: egm96_15.gtx), which PROJ finds for the new ones
_OLD_GRID_NAMES = {"us_nga_egm96_15.tif": ("egm96_15.gtx",), "us_noaa_conus.tif": ("conus",)}


def _grid_available(name: str) -> bool:
    pyproj = _pyproj()
    for folder in (pyproj.datadir.get_data_dir(), pyproj.datadir.get_user_data_dir()):
        for n in (name, *_OLD_GRID_NAMES.get(name, ())):
            if (Path(folder) / n).is_file():
                return True
    return pyproj.network.is_network_enabled()


#: EGM96 geoid heights of NGA's test points (readme of WW15MGH.GRD, INTPT.F: bilinear
#: interpolation of the 15' grid that us_nga_egm96_15.tif holds): lon, lat, N
EGM96_CHECKS = [(-90.2208450, 38.6281550, -31.628), (0.0023000, -0.4667440, 17.329)]


@pytest.mark.parametrize("args", [dict(crs="EPSG:32735", geoid="EGM96"),
                                  dict(crs="EPSG:32735+5773"),
                                  dict(crs="EPSG:32735", geoid="EPSG:5773")])
def test_crs_frame_orthometric_egm96(args):
    if not _grid_available("us_nga_egm96_15.tif"):
        # no grid here (and no network): the conversion must be refused, naming the grid
        with pytest.raises(CRSError, match="EGM96 height") as err:
            crs_frame(heights="orthometric", near=(24.41, -33.67), **args)
        assert "us_nga_egm96_15.tif" in err.value.what
        assert "projsync --file us_nga_egm96_15.tif" in err.value.mend
        assert "PROJ_NETWORK=ON" in err.value.mend
        assert "heights='ellipsoidal'" in err.value.mend
        return
    pyproj = _pyproj()
    for lon, lat, n in EGM96_CHECKS:
        zone = utm_crs(lon, lat)
        crs = args["crs"].replace("EPSG:32735", zone)
        frame = crs_frame(crs, heights="orthometric", geoid=args.get("geoid"), near=(lon, lat))
        x, y = pyproj.Transformer.from_crs("EPSG:4326", zone, always_xy=True).transform(lon, lat)
        llh, jac = frame.to_geodetic([[x, y, 0.0]])
        assert llh[0, 2] == pytest.approx(n, abs=0.02)           # h = H + N with H = 0
        assert jac[0, 2, 2] == pytest.approx(1.0, abs=1e-6)
        assert "EGM96 height" in frame.description


def test_crs_frame_warns_of_a_coarse_datum_shift():
    if _grid_available("us_noaa_conus.tif"):
        pytest.skip("NADCON grid installed: PROJ's NAD27 shift is then accurate")
    with pytest.warns(UserWarning, match="NAD27 / UTM zone 16N to WGS 84 is"):
        frame = crs_frame("EPSG:26716", near=(-87.6, 41.9))
    assert "NAD27" in frame.description

"""CRS equivalence judged by the CRS, not by its name (issue 36): EPSG:3067 as "ETRS89 /
TM35FIN(E,N)" and as "EUREF-FIN / TM35FIN(E,N)" (its datum called "EUREF-FIN", as some
national GeoTIFFs say) is one CRS - no "ballpark transformation" warning, no
transformation at all - while a real datum change still warns."""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest

pyproj = pytest.importorskip("pyproj")

from pyproj import CRS  # noqa: E402

from vectoradjust.files.readers import same_crs, transformation_info  # noqa: E402

#: a box in Helsinki, EPSG:3067
BOUNDS = (380000.0, 6670000.0, 390000.0, 6680000.0)


def euref_fin(keep_id: bool = True) -> CRS:
    """EPSG:3067 renamed "EUREF-FIN / TM35FIN(E,N)", its datum "EUREF-FIN" (GRS 1980);
    with ``keep_id`` it still carries ID["EPSG",3067]."""
    wkt = CRS.from_epsg(3067).to_wkt("WKT2_2019")
    wkt = wkt.replace('"ETRS89 / TM35FIN(E,N)"', '"EUREF-FIN / TM35FIN(E,N)"')
    wkt = wkt.replace('BASEGEOGCRS["ETRS89"', 'BASEGEOGCRS["EUREF-FIN"')
    wkt, n = re.subn(r'ENSEMBLE\["European Terrestrial Reference System 1989 ensemble".*?'
                     r'ENSEMBLEACCURACY\[[0-9.]+\]\]',
                     'DATUM["EUREF-FIN",ELLIPSOID["GRS 1980",6378137,298.257222101,'
                     'LENGTHUNIT["metre",1]]]', wkt, flags=re.S)
    assert n == 1, "PROJ's WKT of EPSG:3067 changed: the datum was not renamed"
    if not keep_id:
        wkt = re.sub(r',\s*ID\["EPSG",3067\]', "", wkt)
    return CRS.from_wkt(wkt)


def test_the_fixture_is_what_pyproj_calls_another_crs():
    """Without :func:`same_crs` pyproj sees two CRSs and PROJ only a ballpark link."""
    other = euref_fin()
    assert other.name == "EUREF-FIN / TM35FIN(E,N)" and other.datum.name == "EUREF-FIN"
    assert not CRS.from_epsg(3067).equals(other)
    _, info = transformation_info(CRS.from_epsg(3067), other, BOUNDS)
    assert info["ballpark"] and "ballpark" in info["warning"]


def test_epsg_3067_under_two_names_is_one_crs():
    a = CRS.from_epsg(3067)
    assert same_crs(a, euref_fin()) and same_crs(euref_fin(), a)
    assert same_crs("EPSG:3067", a.to_wkt("WKT1_ESRI"))  # EUREF_FIN_TM35FIN (ESRI)
    assert same_crs("EPSG:4326", "OGC:CRS84")  # axis order only: every reader uses x, y


def test_a_real_datum_change_is_not_the_same():
    a = CRS.from_epsg(3067)
    assert not same_crs(a, CRS.from_epsg(2393))  # KKJ / Finland Uniform Coordinate System
    assert not same_crs(a, CRS.from_epsg(3047))  # UTM zone 35N: another projection
    # the datum renamed and no code: nothing vouches that EUREF-FIN is ETRS89
    assert not same_crs(a, euref_fin(keep_id=False))
    # a stale code on another ellipsoid (International 1924): the code does not vouch
    intl = euref_fin().to_wkt().replace('ELLIPSOID["GRS 1980",6378137,298.257222101',
                                        'ELLIPSOID["International 1924",6378388,297')
    stale = CRS.from_wkt(intl)
    assert not same_crs(a, stale)
    _, info = transformation_info(a, stale, BOUNDS)
    assert info["warning"] and "ballpark" in info["warning"]


def test_the_dem_in_the_renamed_crs_is_read_without_a_warning(tmp_path):
    """A DEM GeoTIFF in "EUREF-FIN / TM35FIN(E,N)" sampled for an EPSG:3067 project: no
    transformation (the report's ``crs`` is None) and the same heights."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import from_origin

    from vectoradjust.files.readers import sample_dem

    z = np.arange(100, dtype="float32").reshape(10, 10)
    path = tmp_path / "dem.tif"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with rasterio.open(path, "w", driver="GTiff", height=10, width=10, count=1,
                           dtype="float32", crs=rasterio.crs.CRS.from_wkt(euref_fin().to_wkt()),
                           transform=from_origin(385000.0, 6675010.0, 1.0, 1.0)) as dst:
            dst.write(z, 1)
    with rasterio.open(path) as src:
        assert "EUREF-FIN" in src.crs.to_wkt()
    report = {}
    heights = sample_dem(str(path), np.array([[385004.5, 6675004.5]]), "EPSG:3067", report)
    assert report["crs"] is None and report["grid"] is not None
    assert heights[0] == pytest.approx(float(z[5, 4]))

"""Checks of a run on data in memory: a selected database none of whose shape points is
measured, and the warnings summarised once each."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from vectoradjust.errors import MeasurementError, NothingAdjustedError
from vectoradjust.pipeline import distinct_warnings, run
from vectoradjust.simulate import make_scenario


@pytest.fixture(scope="module")
def scenario():
    return make_scenario(0)


def _renamed(data, name: str, prefix: str):
    """``data`` with the feature ids of database ``name`` prefixed (matching nothing)."""
    vectors = []
    for spec, layer in data.vectors:
        if spec.name == name:
            layer = replace(layer, feature_ids=np.char.add(prefix, layer.feature_ids))
        vectors.append((spec, layer))
    data.vectors = vectors
    return data


def test_a_selected_database_without_measured_shape_points_is_an_error(scenario):
    data = _renamed(scenario.to_project_data(), "TNM", "X")
    with pytest.raises(NothingAdjustedError, match=r"^TNM .*match none of the measured ids") as exc:
        run(data, vectors=["TNM"])
    msg = str(exc.value)
    assert msg.startswith("TNM (")
    assert "its shape point ids (id_field = 'permanent_', e.g. 'XTNM-" in msg
    assert "match none of the measured ids (e.g. 'TNM-" in msg
    assert "leave the database out of this run" in msg
    assert isinstance(exc.value, MeasurementError) and exc.value.details == {"database": "TNM"}
    with pytest.raises(NothingAdjustedError, match="^TNM "):
        run(data)  # every database is in the run


def test_an_unselected_database_may_have_no_measured_shape_points(scenario):
    data = _renamed(scenario.to_project_data(), "TIGER", "X")
    r = run(data, vectors=["OSM"])
    assert r.summary["databases"][0]["adjusted_vertices"] > 50


def test_qualified_ids_of_another_name_are_named(scenario):
    data = scenario.to_project_data()
    m = data.measurements
    ids = m.point_id.astype(object)
    osm = np.isin(np.array([i.rsplit("_", 1)[0] for i in ids]),
                  data.vectors[0][1].feature_ids)
    ids[osm] = ["osm:" + i for i in ids[osm]]  # the database is called OSM
    data.measurements = replace(m, point_id=ids)
    with pytest.raises(NothingAdjustedError, match=r"ids are qualified with osm: but the "
                                                   r"databases are named OSM, TIGER, TNM"):
        run(data, vectors=["OSM"])


def test_warnings_are_listed_once_with_their_count():
    ws = ["OSM: identification_sigma is not given", "a", "TNM: identification_sigma is not given",
          "a", "b", "a", "OSMX: c"]
    assert distinct_warnings(ws, ["OSM", "TNM"]) == [
        "OSM, TNM: identification_sigma is not given", "a (3 times)", "b", "OSMX: c"]
    assert distinct_warnings([], ["OSM"]) == []


def test_a_runs_warnings_are_distinct(scenario):
    data = scenario.to_project_data()
    data.vectors = [(replace(spec, identification_sigma=None), layer)
                    for spec, layer in data.vectors]
    r = run(data)
    assert len(set(r.summary["warnings"])) == len(r.summary["warnings"])
    assert r.warnings == r.summary["warnings"]
    ident = [w for w in r.summary["warnings"] if "identification_sigma is not given" in w]
    assert len(ident) >= 1

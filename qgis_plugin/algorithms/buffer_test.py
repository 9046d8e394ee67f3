"""Buffer accuracy test (Goodchild & Hunter 1997) of a line layer against a reference."""

import numpy as np
from qgis.core import (
    Qgis,
    QgsFeatureRequest,
    QgsGeometry,
    QgsProcessing,
    QgsProcessingException,
    QgsProcessingParameterCrs,
    QgsProcessingParameterDefinition,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterNumber,
    QgsProcessingParameterString,
    QgsWkbTypes,
)

from .. import qgis_io
from ..results import add_all
from .base import VectorAdjustAlgorithm, cancel_callback, check_cancelled, progress_callback

#: tested lines intersected with a buffer per step (progress and Cancel between steps)
CHUNK = 2000

HELP = """
<p>The buffer test of line accuracy (Goodchild &amp; Hunter 1997): the reference lines are
buffered by a width <i>x</i>, and the share of the tested lines' total length inside the
buffer is reported for each width, e.g. "98 % of the adjusted roads lie within 1 m of the
surveyed centre lines".</p>
<h3>Needs</h3>
<ul>
<li><b>Tested line layer</b> (e.g. the adjusted road features, or the original database).</li>
<li><b>Reference line layer</b> (the "true" centre lines).</li>
<li><b>Buffer widths</b>: a list of distances in metres, separated by commas or spaces.</li>
<li><b>Ground CRS</b> (optional; projected, metres; default the tested layer's CRS). Both
layers are transformed to it.</li>
</ul>
<p>All reference lines are united before buffering, so overlapping buffers count once. Round
caps and joins are approximated by <i>segments per quarter circle</i> chords (default 32, as in
the vectoradjust core), which makes round parts at most 0.03 % narrow.</p>
<h3>Writes</h3>
<p>A table, one row per width: <code>width</code>, <code>share</code> (0..1),
<code>percent</code>, <code>inside</code> (length inside, m) and <code>total</code> (total
length of the tested lines, m).</p>
<p>The same numbers as <code>vectoradjust.accuracy.buffer.buffer_test</code> (computed here with
QGIS's GEOS instead of shapely).</p>
"""

CAP_STYLES = ["round", "flat", "square"]


def _cap(name):
    return {"round": Qgis.EndCapStyle.Round, "flat": Qgis.EndCapStyle.Flat,
            "square": Qgis.EndCapStyle.Square}[name]


def parse_widths(text):
    """Buffer widths from text ("0.5, 1 2;5") -> list of float."""
    from vectoradjust.errors import VectorAdjustError

    items = [t for t in str(text).replace(";", ",").replace(" ", ",").split(",") if t.strip()]
    if not items:
        raise VectorAdjustError("No buffer widths are given",
                                "Enter widths in metres, e.g. 0.5, 1, 2, 5")
    out = []
    for t in items:
        try:
            w = float(t)
        except ValueError:
            raise VectorAdjustError(f"Buffer width {t.strip()!r} is not a number",
                                    "Enter widths in metres separated by commas") from None
        if not np.isfinite(w) or w < 0:
            raise VectorAdjustError(f"Buffer width {t.strip()!r} must be a finite number >= 0",
                                    "Enter widths in metres, e.g. 0.5, 1, 2, 5")
        out.append(w)
    return out


def _lines(source, crs, context, where, feedback=None):
    from vectoradjust.errors import CRSError, LayerError

    wkb = source.wkbType()
    if QgsWkbTypes.geometryType(wkb) != QgsWkbTypes.LineGeometry:
        raise LayerError(f"{where}: the layer holds {QgsWkbTypes.displayString(wkb) or 'no'} "
                         "geometries, not lines", "Give a line layer")
    if not source.sourceCrs().isValid():
        raise CRSError(f"{where}: the layer has no coordinate reference system",
                       "Set the layer's CRS and run again")
    request = QgsFeatureRequest()
    if source.sourceCrs() != crs:
        request.setDestinationCrs(crs, context.transformContext())
    geoms = []
    for k, f in enumerate(source.getFeatures(request)):
        if k % CHUNK == 0:
            check_cancelled(feedback)
        g = f.geometry()
        if g is None or g.isNull() or g.isEmpty():
            continue
        geoms.append(QgsGeometry(g))
    return geoms


def _buffers(reference, widths, quad_segs=32, cap_style="round", feedback=None):
    """The united reference lines buffered by each width (None: an empty buffer), each
    with a prepared GEOS engine: ``[(buffer, engine) or None]``."""
    parts = []
    for g in reference:
        parts.extend(QgsGeometry(p.clone()) for p in g.constParts())
    ref = QgsGeometry.collectGeometry(parts) if parts else None
    out = []
    for width in widths:
        check_cancelled(feedback)
        if ref is None or width <= 0:
            out.append(None)
            continue
        buf = ref.buffer(float(width), int(quad_segs), _cap(cap_style), Qgis.JoinStyle.Round,
                         5.0)
        engine = QgsGeometry.createGeometryEngine(buf.constGet())
        engine.prepareGeometry()
        out.append((buf, engine))
    return out


def _inside(tested, buffers, step):
    """Length of the tested lines inside each buffer and their total length, in chunks of
    :data:`CHUNK` lines (``step(n)`` after each: progress and Cancel)."""
    total = float(sum(g.length() for g in tested))
    inside = [0.0] * len(buffers)
    for k in range(0, max(len(tested), 1), CHUNK):
        part = tested[k:k + CHUNK]
        for j, b in enumerate(buffers):
            if b is None or total <= 0:
                continue
            buf, engine = b
            inside[j] += sum(g.intersection(buf).length() for g in part
                             if engine.intersects(g.constGet()))
        step(len(part))
    return inside, total


def _share(inside, total):
    return None if total <= 0 else min(max(inside / total, 0.0), 1.0)


def buffer_shares(tested, reference, widths, quad_segs=32, cap_style="round", feedback=None,
                  start=0.0, span=100.0):
    """Share of the tested lines' length inside buffers of the reference lines.

    The QGIS/GEOS twin of :func:`vectoradjust.accuracy.buffer.buffer_test` (same result
    dictionaries): the reference lines' parts are collected into one multi-line and
    buffered; each tested geometry is intersected with the buffer. Reports progress per
    chunk of :data:`CHUNK` tested lines to ``feedback`` (``start`` .. ``start + span``
    percent) and stops with :class:`vectoradjust.errors.CancelledError` on Cancel.
    """
    report = progress_callback(feedback, start, span) if feedback is not None else None
    if report is not None:
        feedback.setProgressText("buffering the reference lines")
    buffers = _buffers(reference, widths, quad_segs, cap_style, feedback)
    done = [0]

    def step(n):
        done[0] += n
        if report is not None:
            report(done[0] / max(len(tested), 1), "intersecting the tested lines")
        check_cancelled(feedback)

    inside, total = _inside(tested, buffers, step)
    return [{"width": float(w), "share": _share(x, total), "length_inside": x,
             "length_total": total} for w, x in zip(widths, inside)]


def _vertex_lines(xy, ranges):
    """LineStrings of the vertex ranges of :func:`vectoradjust.files.truth.line_ranges`."""
    from qgis.core import QgsLineString

    return [QgsGeometry(QgsLineString([float(v) for v in xy[s:e, 0]],
                                      [float(v) for v in xy[s:e, 1]]))
            for s, e in ranges]


def truth_buffer(run, truth_path, widths, crs, context, feedback=None, start=0.0, span=100.0):
    """:func:`vectoradjust.files.truth.truth_buffer` with QGIS reading and GEOS geometry
    (QGIS's Python has no geopandas/shapely): the share of each database's lines inside
    buffers of the true lines before and after the adjustment.

    The core's :func:`~vectoradjust.files.truth.drive_truth_buffer` chooses the lines
    (features with at least one adjusted vertex), reports progress per database and per
    chunk of lines to ``feedback`` (``start`` .. ``start + span`` percent), polls Cancel
    (:class:`vectoradjust.errors.CancelledError`) and writes
    ``run.summary["databases"][i]["truth"]["buffer"]``; returns ``{database: entry}``.

    Parameters
    ----------
    run : AdjustmentRun
    truth_path : str
        The ``[truth] path`` line layer (read through QGIS, transformed to ``crs``).
    widths : list of float
    crs : QgsCoordinateReferenceSystem
        The ground CRS.
    context : QgsProcessingContext
    """
    import os

    from qgis.core import QgsVectorLayer

    from vectoradjust.errors import LayerError
    from vectoradjust.files.truth import drive_truth_buffer

    if not os.path.exists(truth_path):
        raise LayerError(f"Line layer {truth_path!r} does not exist ([truth] path)",
                         "Check the path", path=str(truth_path))
    layer = QgsVectorLayer(str(truth_path), "truth", "ogr")
    if not layer.isValid():
        raise LayerError(f"{truth_path}: cannot be read as a vector layer ([truth] path)",
                         "Give a shapefile, GeoPackage or GeoJSON of lines", path=str(truth_path))
    say = progress_callback(feedback, start, span) if feedback is not None else None
    if say is not None:
        say(0.0, "buffer test: reading the true centrelines")
    truth = _lines(layer, crs, context, f"true centrelines {truth_path!r} ([truth] path)",
                   feedback)
    if say is not None:
        say(0.0, "buffer test: buffering the true centrelines")
    buffers = _buffers(truth, widths, feedback=feedback)

    def shares(xy, ranges, step):
        inside, total = _inside(_vertex_lines(xy, ranges), buffers, step)
        return [_share(x, total) for x in inside]

    return drive_truth_buffer(run, list(widths), shares, truth_path, say,
                              cancel_callback(feedback))


def project_truth_buffer(prj, runs, context, feedback, start=80.0, span=5.0):
    """Apply :func:`truth_buffer` to every run when the project has a ``[truth]`` table
    (true centrelines), as ``vectoradjust adjust`` / ``compare`` do; progress from
    ``start`` to ``start + span`` percent, Cancel ends with CancelledError."""
    from vectoradjust.files.truth import project_truth

    truth = project_truth(prj.spec)
    if truth is None:
        return
    path, widths = truth
    feedback.setProgressText(f"buffer test against the true centrelines {path}")
    each = span / max(len(runs), 1)
    for k, r in enumerate(runs):
        truth_buffer(r, path, widths, prj.crs, context, feedback, start + k * each, each)



def project_truth_lines(prj, runs, context, feedback):
    """Each adjusted point's distance to the nearest true centreline before and after
    (:func:`vectoradjust.files.truth.drive_truth_lines` with GEOS through QGIS) when the
    project has a ``[truth]`` table, as ``vectoradjust adjust`` does: writes
    ``databases[].truth.lines`` (share moved closer) into each run's summary."""
    import os

    from qgis.core import QgsPoint, QgsVectorLayer

    from vectoradjust.files.truth import drive_truth_lines, project_truth

    truth = project_truth(prj.spec)
    if truth is None or not os.path.exists(truth[0]):
        return
    layer = QgsVectorLayer(str(truth[0]), "truth", "ogr")
    if not layer.isValid():
        return
    lines = _lines(layer, prj.crs, context, f"true centrelines {truth[0]!r} ([truth] path)",
                   feedback)
    parts = [QgsGeometry(p.clone()) for g in lines for p in g.constParts()]
    if not parts:
        return
    united = QgsGeometry.collectGeometry(parts)  # kept alive: the engine points into it
    engine = QgsGeometry.createGeometryEngine(united.constGet())
    engine.prepareGeometry()

    def distance(x, y):
        d = engine.distance(QgsPoint(float(x), float(y)))  # (distance, error) in PyQGIS
        return d[0] if isinstance(d, tuple) else d

    def distances(xy):
        check_cancelled(feedback)
        return [distance(x, y) for x, y in xy]

    feedback.setProgressText("distances to the true centrelines")
    for r in runs:
        drive_truth_lines(r, distances, truth[0])


class BufferAccuracyTest(VectorAdjustAlgorithm):
    NAME = "bufferaccuracytest"
    DISPLAY = "Buffer accuracy test"
    SHORT = "Share of a line layer's length within buffers of a reference (Goodchild & Hunter)."
    HELP = HELP

    INPUT = "INPUT"
    REFERENCE = "REFERENCE"
    WIDTHS = "WIDTHS"
    GROUND_CRS = "GROUND_CRS"
    QUAD_SEGS = "QUAD_SEGS"
    CAP_STYLE = "CAP_STYLE"
    OUTPUT = "OUTPUT"

    FIELDS = ["width", "share", "percent", "inside", "total"]

    def initAlgorithm(self, config=None):
        self.addParameter(QgsProcessingParameterFeatureSource(
            self.INPUT, "Tested line layer", [QgsProcessing.TypeVectorLine]))
        self.addParameter(QgsProcessingParameterFeatureSource(
            self.REFERENCE, "Reference line layer", [QgsProcessing.TypeVectorLine]))
        self.addParameter(QgsProcessingParameterString(
            self.WIDTHS, "Buffer widths [m]", defaultValue="0.5, 1, 2, 5, 10"))
        self.addParameter(QgsProcessingParameterCrs(
            self.GROUND_CRS, "Ground CRS (projected, metres; default: tested layer CRS)",
            optional=True))
        p = QgsProcessingParameterNumber(self.QUAD_SEGS, "Segments per quarter circle",
                                         QgsProcessingParameterNumber.Integer, defaultValue=32,
                                         minValue=1)
        p.setFlags(p.flags() | QgsProcessingParameterDefinition.FlagAdvanced)
        self.addParameter(p)
        p = QgsProcessingParameterEnum(self.CAP_STYLE, "Buffer end caps", CAP_STYLES,
                                       defaultValue=0)
        p.setFlags(p.flags() | QgsProcessingParameterDefinition.FlagAdvanced)
        self.addParameter(p)
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Buffer test", QgsProcessing.TypeVector))

    def run_algorithm(self, parameters, context, feedback):
        tested = self.parameterAsSource(parameters, self.INPUT, context)
        reference = self.parameterAsSource(parameters, self.REFERENCE, context)
        if tested is None:
            raise QgsProcessingException(self.invalidSourceError(parameters, self.INPUT))
        if reference is None:
            raise QgsProcessingException(self.invalidSourceError(parameters, self.REFERENCE))
        widths = parse_widths(self.parameterAsString(parameters, self.WIDTHS, context))
        if parameters.get(self.GROUND_CRS) not in (None, ""):
            crs = self.parameterAsCrs(parameters, self.GROUND_CRS, context)
            where = "Ground CRS parameter"
        else:
            crs = tested.sourceCrs()
            where = f"tested layer {tested.sourceName()!r}"
        if not tested.sourceCrs().isValid():
            from vectoradjust.errors import CRSError

            raise CRSError(f"tested layer {tested.sourceName()!r}: the layer has no coordinate "
                           "reference system", "Set the layer's CRS and run again")
        qgis_io.check_ground_crs(crs, where)
        feedback.setProgressText("reading the tested and reference lines")
        t = _lines(tested, crs, context, f"tested layer {tested.sourceName()!r}", feedback)
        feedback.setProgress(5)
        r = _lines(reference, crs, context, f"reference layer {reference.sourceName()!r}",
                   feedback)
        feedback.setProgress(10)
        check_cancelled(feedback)
        cap = CAP_STYLES[self.parameterAsEnum(parameters, self.CAP_STYLE, context)]
        rows = buffer_shares(t, r, widths,
                             self.parameterAsInt(parameters, self.QUAD_SEGS, context), cap,
                             feedback, 10.0, 85.0)
        fields = qgis_io.fields_for(self.FIELDS, {})
        sink, dest = self.parameterAsSink(parameters, self.OUTPUT, context, fields,
                                          QgsWkbTypes.NoGeometry, crs)
        if sink is None:
            raise QgsProcessingException(self.invalidSinkError(parameters, self.OUTPUT))
        feats = []
        for row in rows:
            share = row["share"]
            feats.append(qgis_io.new_feature(fields, [
                row["width"], share, None if share is None else 100.0 * share,
                row["length_inside"], row["length_total"]]))
            feedback.pushInfo(f"width {row['width']:g} m: "
                              + ("no tested length" if share is None else
                                 f"{100.0 * share:.1f} % of {row['length_total']:.1f} m inside"))
        add_all(sink, feats, feedback)
        feedback.setProgress(100)
        return {self.OUTPUT: dest}

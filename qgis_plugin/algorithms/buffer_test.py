"""Buffer accuracy test (Goodchild & Hunter 1997) of a line layer against a reference.

QGIS reads the layers and converts them to arrays; the core measures
(:mod:`vectoradjust.accuracy.buffer`, :mod:`vectoradjust.accuracy.capped_buffer`,
:mod:`vectoradjust.accuracy.line_distances`).
"""

import functools

import numpy as np
from qgis.core import (
    QgsFeatureRequest,
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
<p>All reference lines are united before buffering, so overlapping buffers count once. The
buffers are exact and computed by the vectoradjust core, by segments, linear in the size of
the data (only the reference lines near the tested ones are read): with round end caps (the
default) the points within the width of the reference lines
(<code>vectoradjust buffer-test --exact</code>); with flat or square caps the union of a
rectangle per segment (square caps: running on by the width at a line's free ends) and a
round join at each inner vertex. GEOS's polygon buffers approximate the round joins and caps
by chords, and with flat or square caps they may also cut off part of a line's buffer where
the line ends with a segment shorter than the width after a turn; the numbers here do
neither. <i>Segments per quarter circle</i> is no longer used (kept for saved models).</p>
<h3>Writes</h3>
<p>A table, one row per width: <code>width</code>, <code>share</code> (0..1),
<code>percent</code>, <code>inside</code> (length inside, m) and <code>total</code> (total
length of the tested lines, m).</p>
<p>The same numbers as <code>vectoradjust.accuracy.buffer.buffer_test</code> with
<code>method="exact"</code> (round caps; the polygon buffers of the default method are up to
0.03 % of the width narrower on round caps and joins) and
<code>vectoradjust.accuracy.capped_buffer.capped_buffer_test</code> (flat and square
caps).</p>
"""

CAP_STYLES = ["round", "flat", "square"]


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


def exact_shares(tested, reference, widths, crs, context, feedback=None, cap_style="round"):
    """The buffer test by the core: QGIS reads both layers (the reference only near the
    tested lines) in ``crs`` and converts them; the core measures
    (:func:`vectoradjust.accuracy.buffer.segment_buffer_test` for round caps, the exact
    round buffers of ``vectoradjust buffer-test --exact``;
    :func:`vectoradjust.accuracy.capped_buffer.capped_buffer_test` for flat and square
    caps). Progress 5 .. 95 % per :data:`SEGMENT_CHUNK` tested segments, Cancel between
    them."""
    from vectoradjust.accuracy.buffer import segment_buffer_test
    from vectoradjust.accuracy.capped_buffer import capped_buffer_test

    t = line_segments_of(tested, crs, context, f"tested layer {tested.sourceName()!r}",
                         feedback)
    feedback.setProgress(5)
    rect = segments_rect(t, max(widths, default=0.0) + 1.0)
    where = f"reference layer {reference.sourceName()!r}"
    r = line_parts_of(reference, crs, context, where, feedback, rect)
    feedback.setProgress(10)
    check_cancelled(feedback)
    feedback.setProgressText("intersecting the tested lines")
    report = progress_callback(feedback, 10.0, 85.0)
    done = [0]

    def step(n):
        done[0] += n
        report(done[0] / max(len(t), 1), "intersecting the tested lines")
        check_cancelled(feedback)

    if cap_style == "round":
        return segment_buffer_test(t, parts_to_segments(r), widths, chunk=SEGMENT_CHUNK,
                                   step=step)
    return capped_buffer_test(t, r, widths, cap_style, chunk=SEGMENT_CHUNK, step=step)


def segments_rect(segments, margin):
    """The QgsRectangle around segments ``(n, 2, 2)`` grown by ``margin`` (None without
    segments): the reference lines read for them."""
    from qgis.core import QgsRectangle

    if not len(segments):
        return None
    lo, hi = segments.min(axis=(0, 1)), segments.max(axis=(0, 1))
    return QgsRectangle(float(lo[0] - margin), float(lo[1] - margin), float(hi[0] + margin),
                        float(hi[1] + margin))


#: tested segments measured per step of the exact (round) buffer test
SEGMENT_CHUNK = 50_000


def _parts_xy(geom):
    """The line parts of a geometry as ``(n, 2)`` XY arrays, read from their WKB (one
    numpy call per part, not one Python call per vertex); curves are segmentised."""
    from qgis.core import QgsLineString

    g = geom.constGet()
    parts = ([g.geometryN(k) for k in range(g.numGeometries())]
             if QgsWkbTypes.isMultiType(g.wkbType()) else [g])
    out = []
    for p in parts:
        if p is None:
            continue
        if not isinstance(p, QgsLineString):
            p = p.curveToLine() if hasattr(p, "curveToLine") else None
            if p is None:
                continue
        n = p.numPoints()
        if n < 2:
            continue
        wkb = bytes(p.asWkb())
        dim = 2 + QgsWkbTypes.hasZ(p.wkbType()) + QgsWkbTypes.hasM(p.wkbType())
        order = "<" if wkb[0] == 1 else ">"
        xyz = np.frombuffer(wkb, dtype=f"{order}f8", count=n * dim, offset=9)
        out.append(xyz.reshape(n, dim)[:, :2])
    return out


def line_parts_of(source, crs, context, where, feedback=None, rect=None):
    """The line parts of a line layer in ``crs``, each an ``(k, 2)`` XY array (QGIS only
    reads and converts).

    ``rect`` (QgsRectangle in ``crs``, optional): only the features whose bounding box
    meets it (the lines near the tested ones; the others add nothing to a buffer or a
    nearest distance inside it). Polls Cancel every :data:`CHUNK` features.
    """
    from vectoradjust.errors import CRSError, LayerError

    wkb = source.wkbType()
    if QgsWkbTypes.geometryType(wkb) != QgsWkbTypes.LineGeometry:
        raise LayerError(f"{where}: the layer holds {QgsWkbTypes.displayString(wkb) or 'no'} "
                         "geometries, not lines", "Give a line layer")
    if not source.sourceCrs().isValid():
        raise CRSError(f"{where}: the layer has no coordinate reference system",
                       "Set the layer's CRS and run again")
    request = QgsFeatureRequest().setNoAttributes()
    if source.sourceCrs() != crs:
        request.setDestinationCrs(crs, context.transformContext())
    if rect is not None:
        request.setFilterRect(rect)  # in the destination CRS when one is set
    parts = []
    for k, f in enumerate(source.getFeatures(request)):
        if k % CHUNK == 0:
            check_cancelled(feedback)
        g = f.geometry()
        if g is None or g.isNull() or g.isEmpty():
            continue
        parts.extend(_parts_xy(g))
    return parts


def parts_to_segments(parts):
    """The straight segments ``(n, 2, 2)`` of line parts, as
    :func:`vectoradjust.accuracy.buffer.line_segments`: segments never join two parts,
    zero-length segments and those without coordinates are dropped."""
    segs = [np.stack([xy[:-1], xy[1:]], axis=1) for xy in parts]
    if not segs:
        return np.zeros((0, 2, 2))
    seg = np.concatenate(segs)
    keep = np.any(seg[:, 0] != seg[:, 1], axis=1) & np.isfinite(seg).all(axis=(1, 2))
    return seg[keep]


def line_segments_of(source, crs, context, where, feedback=None, rect=None):
    """The straight segments ``(n, 2, 2)`` of a line layer in ``crs``, for the core's
    :class:`vectoradjust.accuracy.buffer.SegmentBuffer`: :func:`parts_to_segments` of
    :func:`line_parts_of`."""
    return parts_to_segments(line_parts_of(source, crs, context, where, feedback, rect))


def runs_extent(runs, margin):
    """The bounding box (QgsRectangle) of every database vertex of ``runs``, before and
    after the adjustment, grown by ``margin``; None without vertices."""
    from qgis.core import QgsRectangle

    boxes = []
    for r in runs:
        for d in r.databases:
            for xy in (d.shape.layer.coords[:, :2], d.adjusted_coords[:, :2]):
                xy = np.asarray(xy, float)
                xy = xy[np.isfinite(xy).all(axis=1)]
                if len(xy):
                    boxes.append(np.r_[xy.min(axis=0), xy.max(axis=0)])
    if not boxes:
        return None
    b = np.asarray(boxes)
    lo, hi = b[:, :2].min(axis=0) - margin, b[:, 2:].max(axis=0) + margin
    return QgsRectangle(float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))


#: true lines read beyond the tested lines' box (m, besides the widest buffer): the
#: nearest true line of most points is inside it (the others read the whole layer)
TRUTH_MARGIN = 100.0


class TrueLines:
    """The ``[truth]`` centrelines near the tested lines, read once per run through QGIS
    and measured with the core's :class:`vectoradjust.accuracy.buffer.SegmentBuffer`
    (the command line's implementation: the exact round buffers, the nearest distances).

    Parameters
    ----------
    path : str
        The ``[truth] path`` line layer.
    crs : QgsCoordinateReferenceSystem
        The ground CRS.
    context : QgsProcessingContext
    rect : QgsRectangle or None
        Only the true lines whose box meets it are read (:func:`runs_extent`).
    feedback : QgsProcessingFeedback, optional
    """

    def __init__(self, path, crs, context, rect=None, feedback=None):
        import os

        from qgis.core import QgsVectorLayer

        from vectoradjust.accuracy.buffer import SegmentBuffer
        from vectoradjust.errors import LayerError

        if not os.path.exists(path):
            raise LayerError(f"Line layer {path!r} does not exist ([truth] path)",
                             "Check the path", path=str(path))
        self.layer = QgsVectorLayer(str(path), "truth", "ogr")
        if not self.layer.isValid():
            raise LayerError(f"{path}: cannot be read as a vector layer ([truth] path)",
                             "Give a shapefile, GeoPackage or GeoJSON of lines", path=str(path))
        self.path, self.crs, self.context, self.rect = str(path), crs, context, rect
        self.where = f"true centrelines {path!r} ([truth] path)"
        self.segments = line_segments_of(self.layer, crs, context, self.where, feedback, rect)
        self.buffers = SegmentBuffer(self.segments)
        self._all = None  # every true line, read when a point's nearest may lie beyond rect

    def _box(self):
        """:attr:`rect` as ``(xmin, ymin, xmax, ymax)``, or None."""
        r = self.rect
        return None if r is None else (r.xMinimum(), r.yMinimum(), r.xMaximum(), r.yMaximum())

    def distances(self, xy, feedback=None):
        """Each point's distance to the nearest true line (NaN without coordinates): the
        core's grid of segments for the near points, the whole layer's segments (GEOS
        would give the same) for the few whose nearest line may not have been read
        (:mod:`vectoradjust.accuracy.line_distances`)."""
        from vectoradjust.accuracy.buffer import SegmentBuffer
        from vectoradjust.accuracy.line_distances import nearest_distances, room_in_box

        xy = np.asarray(xy, float).reshape(-1, 2)
        check_cancelled(feedback)
        d = np.full(len(xy), np.nan)
        ok = np.flatnonzero(np.isfinite(xy).all(axis=1))
        check = functools.partial(check_cancelled, feedback)
        if len(self.segments):
            d[ok] = nearest_distances(self.buffers, xy[ok], check)
        far = ok[~(d[ok] <= room_in_box(xy[ok], self._box()))]
        if len(far) and self.rect is not None:
            if self._all is None:
                seg = line_segments_of(self.layer, self.crs, self.context, self.where,
                                       feedback)
                self._all = SegmentBuffer(seg) if len(seg) else False
            if self._all is not False:
                d[far] = nearest_distances(self._all, xy[far], check)
        return d


def truth_buffer(run, truth_path, widths, crs, context, feedback=None, start=0.0, span=100.0,
                 truth=None):
    """:func:`vectoradjust.files.truth.truth_buffer` with QGIS reading: the share of each
    database's lines inside the exact round buffers of the true lines before and after
    the adjustment, measured by the core's code (the same as ``vectoradjust adjust``).

    The core's :func:`~vectoradjust.files.truth.drive_truth_buffer` chooses the lines
    (features with at least one adjusted vertex), reports progress per database and per
    chunk of ``vectoradjust.files.truth.TRUTH_CHUNK`` lines to ``feedback`` (``start`` ..
    ``start + span`` percent), polls Cancel (:class:`vectoradjust.errors.CancelledError`)
    and writes ``run.summary["databases"][i]["truth"]["buffer"]``; returns
    ``{database: entry}``.

    Parameters
    ----------
    run : AdjustmentRun
    truth_path : str
        The ``[truth] path`` line layer (read through QGIS, transformed to ``crs``).
    widths : list of float
    crs : QgsCoordinateReferenceSystem
        The ground CRS.
    context : QgsProcessingContext
    truth : TrueLines, optional
        The true lines already read (else read here, those near the run's lines).
    """
    from vectoradjust.files import truth as core_truth

    widths = [float(w) for w in widths]
    say = progress_callback(feedback, start, span) if feedback is not None else None
    if truth is None:
        if say is not None:
            say(0.0, "buffer test: reading the true centrelines")
        rect = runs_extent([run], max(widths, default=0.0) + TRUTH_MARGIN)
        truth = TrueLines(truth_path, crs, context, rect, feedback)
    if say is not None:
        say(0.0, "buffer test: indexing the true centrelines")

    def shares(xy, ranges, step):
        return core_truth._shares(xy, ranges, truth.buffers, widths, step)

    return core_truth.drive_truth_buffer(run, widths, shares, truth_path, say,
                                         cancel_callback(feedback))


def read_project_truth(prj, runs, context, feedback):
    """The project's ``[truth]`` lines near the runs' lines (:class:`TrueLines`, read
    once for the buffer test and the distances) and its widths; None without
    ``[truth]``."""
    from vectoradjust.files.truth import project_truth

    truth = project_truth(prj.spec)
    if truth is None:
        return None
    path, widths = truth
    feedback.setProgressText("buffer test: reading the true centrelines")
    rect = runs_extent(runs, max(widths, default=0.0) + TRUTH_MARGIN)
    return TrueLines(path, prj.crs, context, rect, feedback), widths


def project_truth_buffer(prj, runs, context, feedback, start=80.0, span=5.0, truth=None):
    """Apply :func:`truth_buffer` to every run when the project has a ``[truth]`` table
    (true centrelines), as ``vectoradjust adjust`` / ``compare`` do; progress from
    ``start`` to ``start + span`` percent, Cancel ends with CancelledError. ``truth``:
    :func:`read_project_truth`'s result (else read here). Returns it (for
    :func:`project_truth_lines`), or None without ``[truth]``."""
    truth = truth or read_project_truth(prj, runs, context, feedback)
    if truth is None:
        return None
    lines, widths = truth
    feedback.setProgressText(f"buffer test against the true centrelines {lines.path}")
    each = span / max(len(runs), 1)
    for k, r in enumerate(runs):
        truth_buffer(r, lines.path, widths, prj.crs, context, feedback, start + k * each, each,
                     truth=lines)
    return truth


def lines_exist(lines, feedback=None):
    """Whether the true lines have a segment at all (the command line then writes no
    distance table): those near the tested lines, else the whole layer's."""
    if len(lines.segments):
        return True
    return lines.rect is not None and len(line_segments_of(
        lines.layer, lines.crs, lines.context, lines.where, feedback)) > 0


def project_truth_lines(prj, runs, context, feedback, truth=None):
    """Each adjusted point's distance to the nearest true centreline before and after
    (:func:`vectoradjust.files.truth.drive_truth_lines` with the core's grid of
    segments) when the project has a ``[truth]`` table, as ``vectoradjust adjust`` does:
    writes ``databases[].truth.lines`` (share moved closer) into each run's summary.
    ``truth``: :func:`read_project_truth`'s result (else read here)."""
    from vectoradjust.files.truth import drive_truth_lines

    truth = truth or read_project_truth(prj, runs, context, feedback)
    if truth is None or not lines_exist(truth[0], feedback):
        return
    lines = truth[0]
    feedback.setProgressText("distances to the true centrelines")
    say = progress_callback(feedback, 85.0, 0.0)
    for r in runs:
        drive_truth_lines(r, lambda xy: lines.distances(xy, feedback), lines.path,
                          progress=say)


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
        # not used since the buffers are exact (kept so that saved models still run)
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
        cap = CAP_STYLES[self.parameterAsEnum(parameters, self.CAP_STYLE, context)]
        rows = exact_shares(tested, reference, widths, crs, context, feedback, cap)
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

"""GDAL's messages during a run, in the Processing log, duplicates folded.

QGIS leaves GDAL's default error handler in place outside the desktop, so the warnings
of the OGR drivers (e.g. the OSM driver's "Non closed ring detected ..." for every
multipolygon it assembles) go to stderr, once per feature and per reading. While an
algorithm runs, :func:`gdal_messages` pushes a handler for its thread (GDAL's handler
stack is per thread) that collects them; at the end each distinct message is one
warning of the Processing log, with how often it came. The GDAL is QGIS's own
(``osgeo`` of the same library), never a second one.
"""

import contextlib

__all__ = ["gdal_messages", "fold", "keep_for", "kept_for", "MAX_DISTINCT"]

#: GDAL's error classes (CPLErr) reported; CE_None and CE_Debug are not
CLASSES = {2: "warning", 3: "error", 4: "fatal error"}

#: distinct messages written to the log (the rest are counted)
MAX_DISTINCT = 20


def fold(messages):
    """Log lines of collected messages ``{(class, text): count}``, in the order they
    first came: ``GDAL warning: <text> (12 times)``; at most :data:`MAX_DISTINCT`, then
    one line counting the others."""
    lines = []
    for k, ((cls, text), n) in enumerate(messages.items()):
        if k == MAX_DISTINCT:
            rest = sum(list(messages.values())[k:])
            lines.append(f"GDAL: {len(messages) - k} more distinct messages ({rest} in all)")
            break
        lines.append(f"GDAL {CLASSES.get(cls, 'message')}: {text}"
                     + (f" ({n} times)" if n > 1 else ""))
    return lines


#: messages of the parameter check (which opens the layers), per processing context,
#: until the run reports them (the check and the run are two instances of the algorithm)
_KEPT: dict = {}


def keep_for(context, seen) -> None:
    """Keep the messages ``seen`` of the parameter check for the run of ``context``."""
    if len(_KEPT) > 100:  # checks whose run never came (a failed check): forget them
        _KEPT.clear()
    if seen:
        for key, n in seen.items():
            store = _KEPT.setdefault(id(context), {})
            store[key] = store.get(key, 0) + n


def kept_for(context) -> dict:
    """The messages kept for ``context`` (and forget them)."""
    return _KEPT.pop(id(context), {})


@contextlib.contextmanager
def gdal_messages(feedback, before=None):
    """Collect GDAL's warnings and errors of the current thread while the block runs and
    push them, folded (:func:`fold`, after those of ``before``, a dictionary of earlier
    messages), to ``feedback`` as warnings at its end (also when it raises). Without
    ``osgeo`` (QGIS's GDAL bindings) the block runs unchanged.

    Yields the ``{(class, text): count}`` dictionary being filled.
    """
    seen = dict(before or {})
    try:
        from osgeo import gdal
    except ImportError:  # pragma: no cover - QGIS ships osgeo
        yield seen
        return

    def handler(err_class, err_no, text):
        try:
            if int(err_class) in CLASSES:
                key = (int(err_class), str(text).strip())
                seen[key] = seen.get(key, 0) + 1
        except Exception:  # noqa: BLE001 - never raise into GDAL
            pass

    gdal.PushErrorHandler(handler)
    try:
        yield seen
    finally:
        gdal.PopErrorHandler()
        if feedback is not None:
            for line in fold(seen):
                feedback.pushWarning(line)

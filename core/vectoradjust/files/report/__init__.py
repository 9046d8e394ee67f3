"""``report.html``: one self-contained HTML report of an adjustment.

:func:`write_report` writes a single file with inline CSS and the figures embedded as
PNG data URIs (no scripts, no external links or resources), so it can be mailed,
archived or opened in QGIS's browser as it is. Sections: summary with the chi-square
verdict, the images' exterior orientation with sigmas, control and check points, the
road databases (and the truth comparison of simulations), accuracy statements
(:mod:`vectoradjust.accuracy.statements`), the precision of the adjusted points, the image
residuals and flagged observations, features, shape points, the QA verdict when given,
and warnings. :func:`write_compare_report` does the same for ``vectoradjust compare``
(each database adjusted alone): the comparison table, the RMSE chart across the
databases and one set of sections per database (:func:`compare_section`: built by the
process that writes the database's own report, inside one
:func:`~vectoradjust.files.report.figures.figure_memo`, so that the figures the two
share are drawn once).

Figures (matplotlib, imported lazily, Agg canvas only, no pyplot, so a running QGIS
session is not disturbed): residual vectors over the road lines
(:func:`residual_vector_figure`), 90 % error ellipses (:func:`error_ellipse_figure`),
standardized image residuals (:func:`residual_histogram_figure`) and RMSE per
database (:func:`rmse_bar_figure`). For large runs the arrows and ellipses are a
random subsample (fixed seed) and the figure says so; the shape points table then
lists the largest residuals only (the full data are in ``adjusted.gpkg``).

The package's modules, by section of the report:

- :mod:`~vectoradjust.files.report.page` - the public API (:func:`write_report`,
  :func:`report_html`, :func:`write_compare_report`, :func:`compare_report_html`): the
  order of the sections, the page and the atomic write.
- :mod:`~vectoradjust.files.report.sections` - summary, images, control and check
  points, road databases, accuracy statements, error model, conflation, warnings; the
  document with its table of contents and the progress/cancel hooks.
- :mod:`~vectoradjust.files.report.listings` - the long tables: features, shape points,
  image residuals, flagged observations and the QA verdict (bounded in size).
- :mod:`~vectoradjust.files.report.maps` - the map figures: residual vectors, the
  conflation field, error ellipses.
- :mod:`~vectoradjust.files.report.figures` - the figure machinery (style, PNG, shared
  map helpers) and the charts: residual histogram, RMSE per database.
- :mod:`~vectoradjust.files.report.markup` - HTML escaping, number formatting, tables,
  the CSS.

The package re-exports the public names, and (``name as name``) the private ones that
:mod:`~vectoradjust.files.study_report` and the tests use. A patched name must be
patched in the module that looks it up (e.g. ``_img`` in
``sections``, ``listings`` and ``page``; the table bounds in ``listings``;
``MAX_SEGMENTS`` in ``figures``).
"""

from __future__ import annotations

from vectoradjust.files.report.figures import _PALETTE as _PALETTE
from vectoradjust.files.report.figures import (
    MAX_SEGMENTS,
    figure_png,
    residual_histogram_figure,
    rmse_bar_figure,
)
from vectoradjust.files.report.figures import _img as _img
from vectoradjust.files.report.figures import _new_figure as _new_figure
from vectoradjust.files.report.figures import _origin as _origin
from vectoradjust.files.report.figures import _segments as _segments
from vectoradjust.files.report.listings import (
    LARGEST_FEATURE_ROWS,
    LARGEST_FLAGGED_ROWS,
    LARGEST_SHAPE_ROWS,
    MAX_FEATURE_ROWS,
    MAX_FULL_SHAPE_ROWS,
)
from vectoradjust.files.report.maps import (
    DENSE_SEGMENTS,
    MAX_ARROWS,
    MAX_ELLIPSES,
    conflation_figure,
    error_ellipse_figure,
    residual_vector_figure,
)
from vectoradjust.files.report.markup import _fmt as _fmt
from vectoradjust.files.report.markup import _table as _table
from vectoradjust.files.report.page import _page as _page
from vectoradjust.files.report.page import _prepare as _prepare
from vectoradjust.files.report.page import _write_text as _write_text
from vectoradjust.files.report.page import (
    compare_report_html,
    compare_section,
    report_html,
    write_compare_report,
    write_report,
)
from vectoradjust.files.report.sections import _Doc as _Doc

__all__ = [
    "write_report",
    "write_compare_report",
    "report_html",
    "compare_report_html",
    "compare_section",
    "residual_vector_figure",
    "error_ellipse_figure",
    "conflation_figure",
    "residual_histogram_figure",
    "rmse_bar_figure",
    "figure_png",
    "MAX_ARROWS",
    "MAX_ELLIPSES",
    "MAX_FULL_SHAPE_ROWS",
    "LARGEST_SHAPE_ROWS",
    "MAX_FEATURE_ROWS",
    "LARGEST_FEATURE_ROWS",
    "LARGEST_FLAGGED_ROWS",
    "MAX_SEGMENTS",
    "DENSE_SEGMENTS",
]

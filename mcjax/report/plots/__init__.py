"""The report's figures: a sweep's error metric, divergence rate and graph connectivity
against its swept axes, as matplotlib figures and PNG files, each with a caption.

* :func:`plots` -- :class:`Plot` (file name, Figure, caption) and :class:`Skipped` (a plot
  not drawn, and why) records for a runs table (see its docstring for the plot kinds).
* :func:`figures` -- the ``(file name, Figure)`` pairs of :func:`plots`, unsaved.
* :func:`make_plots` / :func:`write_plots` -- write those figures as PNG files to
  ``OUT/report/`` (the paths; the paths with captions and the skipped plots).
* :func:`x_axis` -- how an axis' values are placed on the x axis (:class:`XAxis`).
* :func:`filter_colors` -- one colour per filter, by the metadata's display order.

Honest plots, by rule:

* every point shows the number of runs it rests on wherever that number varies within a
  figure (else the subtitle gives it once);
* a point resting on fewer than :data:`MIN_RUNS` runs is drawn hollow, with no interval,
  and lines do not pass through it;
* nothing is pooled over another swept axis silently: a plot against one axis draws one
  panel per value of the other axes (one line per value for the connectivity plot, which
  does not depend on the filter); only beyond :data:`MAX_PANELS` combinations (and in the
  heatmaps of three or more axes) are runs pooled, and then the title says over what and
  why; a metric that does not depend on the plotted axis at all (equal in every run at
  every value) is not plotted against it (a :class:`Skipped` record says so);
* a plotted mean spanning more than a decade is drawn on a log axis (the heatmaps' colour
  scale too: :data:`~mcjax.report.plots.common.LOG_Y_DECADES`); rates are shown in percent;
* axes are in the parameter's display unit (km, deg, ...: :func:`mcjax.analysis.tables.display`)
  and every number is formatted by :func:`mcjax.analysis.tables.format_number`, as in the tables.

Titles and labels come from the dataset's metadata (:mod:`mcjax.analysis.tables`). A scenario
without a divergence flag gets no divergence plots; one without graph statistics (e.g. a
single agent) gets no connectivity plot.

PNG files are written at :data:`~mcjax.report.plots.common.DPI` (twice the figures' layout
resolution), so a page showing them at their layout size stays sharp on high-density screens.

Figures are :class:`matplotlib.figure.Figure` objects drawn on an explicit Agg canvas,
never :mod:`matplotlib.pyplot`: the global backend and pyplot's figure registry are left
untouched and nothing needs a display.  This package does not import JAX.

Modules: :mod:`~mcjax.report.plots.common` (records, constants, axes, colours, drawing helpers),
:mod:`~mcjax.report.plots.lines` (statistics and connectivity against one axis),
:mod:`~mcjax.report.plots.heatmaps` (two axes), :mod:`~mcjax.report.plots.bars` (a single point),
:mod:`~mcjax.report.plots.sensitivity` (the error and its derivatives by Params against one axis),
:mod:`~mcjax.report.plots.catalog` (which figures a table gets; writing them).
"""

from mcjax.report.plots.catalog import figures, make_plots, plots, write_plots
from mcjax.report.plots.common import (MAX_PANELS, MIN_RUNS, PALETTE, SAME_RTOL, Plot, PlotFile, Skipped, XAxis, filter_colors,
                                x_axis)

__all__ = ["PALETTE", "MIN_RUNS", "MAX_PANELS", "SAME_RTOL", "XAxis", "Plot", "Skipped", "PlotFile", "x_axis",
           "filter_colors", "plots", "figures", "write_plots", "make_plots"]

"""A project run from its file to a finished output folder, and the processes beside it.

- :mod:`~vectoradjust.runner.project_run` - :func:`run_project` (read -> adjust ->
  truth -> outputs -> qa -> report), :class:`RunOptions`, :class:`ProjectResult`,
  :func:`read_project`; used by ``adjust``, ``demo``, ``compare`` and ``adjust-many``.
- :mod:`~vectoradjust.runner.alongside` - the stages run in forked processes beside the
  parent (the truth tests' first half, the band kernels, the uncertainty bands, the
  report) and the band processes' covariance files.
- :mod:`~vectoradjust.runner.background` - a stage in a forked child
  (:class:`~vectoradjust.runner.background.Background`), imports in a thread
  (:class:`~vectoradjust.runner.background.Preload`), the number of processes to use.
"""

from __future__ import annotations

from vectoradjust.runner.project_run import (
    Project,
    ProjectResult,
    RunOptions,
    read_project,
    run_project,
)

__all__ = ["Project", "ProjectResult", "RunOptions", "read_project", "run_project"]

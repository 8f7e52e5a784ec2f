"""Presentation of results: what ``hbvs report`` (and ``sweep``) show and export.

* :mod:`.build` -- a run's report as JSON-ready numbers (metrics, verdict, tolerances);
* :mod:`.table` -- the report and fit tables on the terminal;
* :mod:`.plots`, :mod:`.fit_plot`, :mod:`.figure_style` -- figures of runs and fits;
* :mod:`.tum` -- trajectories in TUM format (evo and other tools);
* :mod:`.sweep_summary`, :mod:`.sweep_plots` -- the summary and figures of a sweep.

Submodules are imported by name: importing this package loads no plotting library.
"""

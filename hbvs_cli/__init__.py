"""hbvs: teach-and-repeat for wheeled mobile robots with one camera.

The homography-based adaptive visual servo tracking controller of J. Chen, W. E. Dixon,
D. M. Dawson and M. McIntyre, "Homography-Based Visual Servo Tracking Control of a Wheeled
Mobile Robot", IEEE/RSJ IROS 2003, as a command-line tool: ``hbvs teach``, ``hbvs fit``,
``hbvs repeat``, ``hbvs report`` (and ``hbvs demo``, all four in one).

Layout (data flows one way, teach -> fit -> repeat -> report):

* :mod:`hbvs_cli.core`: the method, pure numpy in and out (camera, homography,
  decomposition, controller, trajectory, the closed loop);
* :mod:`hbvs_cli.perception`: images in, target points out (the detectors);
* :mod:`hbvs_cli.sim`: what a simulated camera sees (renderer, the repeat's world and camera);
* :mod:`hbvs_cli.io`: the edge to files (MCAP, calibration, image sources, CSV, TOML);
* :mod:`hbvs_cli.stages`: one module per subcommand, the core called through the edge;
* :mod:`hbvs_cli.report`: report tables, metrics output, plots, TUM export;
* :mod:`hbvs_cli.sweep`: many runs of repeat on Dask;
* :mod:`hbvs_cli.cli`: the typer command line, a thin layer.
"""

__version__ = "0.1.0"

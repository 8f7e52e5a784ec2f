"""hbvs: teach-and-repeat for wheeled mobile robots with one camera.

The homography-based adaptive visual servo tracking controller of J. Chen, W. E. Dixon,
D. M. Dawson and M. McIntyre, "Homography-Based Visual Servo Tracking Control of a Wheeled
Mobile Robot", IEEE/RSJ IROS 2003, as a command-line tool: ``hbvs teach``, ``hbvs fit``,
``hbvs repeat``, ``hbvs report`` (and ``hbvs demo``, all four in one).

Layout: docs/layout.md.
"""

__version__ = "0.1.0"

"""The method of Chen et al. (IROS 2003), pure: numpy in, numpy out, no I/O, no printing.

One concept per module:

* :mod:`.frames`: rotations, planar poses, the paper <-> OpenCV axes (3)-(5)
* :mod:`.camera`: intrinsics and pixels <-> normalised coordinates (9), (11)
* :mod:`.homography`: the Euclidean homography, three-point (16)-(18) and projective
* :mod:`.decomposition`: the four decompositions of H into (theta, x_h, n*), and the right branch
* :mod:`.plane`: the plane normal n* common to a sequence, refined with the reference points
* :mod:`.known_normal`: (theta, x_h) from the points once n* is known; the point Jacobian
* :mod:`.estimation`: target pixels -> the controller's measurement, with outlier gating
* :mod:`.controller`: errors (19), (27), the law (29)-(31), Lyapunov function (36)
* :mod:`.state_filter`: the Kalman filter on (theta, x_h) between the camera and the law
* :mod:`.gains`: gains from x_hd1_dot and the detector's noise
* :mod:`.trajectory`: the desired trajectory of Remark 1 (splines), condition (35)
* :mod:`.depth`: initial depth estimates from (25) or a known target size
* :mod:`.unicycle`: exact integration of the kinematics (21)
* :mod:`.path`: teach-pendant command profiles and presets
* :mod:`.simulator`: one control period: actuator limits, the step record
* :mod:`.fit_model`: what a fit hands to repeat
* :mod:`.metrics`: statistics and convergence measures of a run
* :mod:`.desired`: the fit of a taught run, pixels in, the desired trajectory out
* :mod:`.labels`: enumerations that files record as words
* :mod:`.grayscale`: camera frames as gray arrays (what detectors and the renderer take)
* :mod:`.assignment`: the assignment of least total cost (point identity)
"""

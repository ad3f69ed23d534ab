"""vnav: the geometry and perception library of vnav-sim.

Rotations (``so3``), quaternions (``quat``, scalar last), rigid transforms (``se3``), frame
conventions and a frame tree (``frames``), the pinhole camera and depth images (``camera``),
the traffic cone and its visibility (``cone``), cone detection (``detect``), the silhouette's
geometry (``silhouette``), the estimators (``estimators``) and their orchestration
(``localize``), the localisation methods and their accuracy contract (``methods``), error
statistics (``metrics``), the frame-bug doctor (``diagnose``), and navigation: the cones seen
as obstacles (``obstacle_map``) and the shortest path around them (``navigate``). numpy and
OpenCV only; it never imports MuJoCo or Rerun.
Conventions: docs/CONVENTIONS.md.
"""

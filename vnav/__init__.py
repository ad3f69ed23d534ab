"""vnav: the geometry and perception library of vnav-sim.

Rotations (`so3`), quaternions (`quat`, scalar last), rigid transforms (`se3`), frame
conventions and a frame tree (`frames`), the pinhole camera (`camera`), the traffic cone's
physical description (`cone`), cone detection (`detect`), localisation (`localize`) and error
statistics (`metrics`). numpy and OpenCV only; it never imports MuJoCo or Rerun. Conventions:
docs/CONVENTIONS.md.
"""

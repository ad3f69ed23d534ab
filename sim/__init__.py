"""sim: everything MuJoCo. Builds scenes, flies the quadrotor, renders, reports ground truth.

Ground truth is returned in vnav's conventions (docs/CONVENTIONS.md).
"""

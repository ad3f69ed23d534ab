"""MJCF models (quadrotor, cone, scene), written here from primitives and shipped as data."""

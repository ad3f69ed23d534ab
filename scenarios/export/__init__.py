"""A finished run in the formats other tools read: each exporter (``base.Exporter``) watches
the run as its recording does and writes its files whole beside the run's own."""

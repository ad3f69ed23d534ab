"""Speed measurements that print figures: ``python -m benchmarks NAME [--json]``."""

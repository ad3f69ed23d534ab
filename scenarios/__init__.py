"""scenarios: scripted headless scenarios, the ``vnav-demo`` command line and Rerun recording."""

"""The scenario format: what a scenario is (``spec``), the keys a file may hold (``schema``),
the check kinds a file may ask for (``check_kinds``), the built-in scenarios (``builtin``) and
writing a scenario back as TOML (``toml_out``). Needs neither MuJoCo nor Rerun."""

"""Built-in plant configurations (one TOML file per plant).

This folder is installed as the package ``containergym_marl.configs`` (see pyproject.toml) so
that ``load_config("n5_m2_dt120")`` works after a non-editable install too.
"""

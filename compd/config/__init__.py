"""The daemon config: one TOML file, every error a `ConfigError` naming the
dotted key path (exit 78).

- `schema`  the sections as pydantic models (shape and single-section checks)
- `loader`  reads the file and runs the checks that span sections
- `model_section` a ``[model]``-form table's model built and checked against the
            config, its identity, the recorder-only stand-in
"""

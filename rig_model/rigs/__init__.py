"""Rig files shipped with the package (TOML, `rig_model.params.NAMED_RIGS`)."""

"""Rig files shipped with the package (TOML, `simulated_hw.params.NAMED_RIGS`)."""

"""A second independent generator of measured SFD-rig data: frequency-domain harmonic balance."""

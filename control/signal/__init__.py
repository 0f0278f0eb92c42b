"""Signal algorithms, no I/O: phase-continuous sine synthesis, the lock-in, the amplitude
controller."""

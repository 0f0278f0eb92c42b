"""The daemon: its state machine, its commands, the acquisition thread, the one-instance locks."""

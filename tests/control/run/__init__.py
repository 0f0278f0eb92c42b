"""Tests of control.run."""

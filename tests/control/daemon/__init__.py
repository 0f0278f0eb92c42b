"""Tests of control.daemon."""

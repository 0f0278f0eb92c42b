"""Tests of control.signal."""

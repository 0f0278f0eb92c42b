"""Tests of control.wire."""

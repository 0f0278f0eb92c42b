"""Tests of control.commissioning."""

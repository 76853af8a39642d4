"""Densities to sample: analytic targets (and later light transport)."""

from . import analytic as analytic

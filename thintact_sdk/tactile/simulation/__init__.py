"""Tactile scene simulation: indenters, lighting, the elastic half-space and loaded presses."""

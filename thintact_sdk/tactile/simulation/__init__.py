"""Tactile scene simulation: indenters, lighting, the elastomer's smoothing, the elastic half-space and loaded presses."""

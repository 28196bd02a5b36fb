"""The device runtime: sensors and groups, cameras through the registry, the capture loop, the virtual bench."""

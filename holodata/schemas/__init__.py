"""JSON Schemas shipped with holodata (dataset root/scene attributes, metrics.json)."""

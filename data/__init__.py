"""Shipped sample data: the demo recipe (installed as package data, read by ``planar-vo demo``).

The TUM frames beside it are test fixtures and are not installed."""

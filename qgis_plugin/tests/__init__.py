"""Tests of the QGIS plugin (run inside Debian's QGIS)."""

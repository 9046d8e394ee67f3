"""Data package: the sample project (sample/) and QGIS styles (styles/) of vectoradjust."""

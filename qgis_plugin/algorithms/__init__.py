"""The vectoradjust Processing algorithms."""

"""The detection methods shipped with slidewatch, one module each (see detection_methods.py)."""

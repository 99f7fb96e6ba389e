"""Pure physics and sensing: target motion, platforms, sensors. No filters, no graphs."""

"""icenav.devices.canopen."""

"""The console's widgets: each formats data the app gives it and reports user intent as messages."""

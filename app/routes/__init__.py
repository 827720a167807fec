"""HTTP routes: rendering, health and version, and the web page."""

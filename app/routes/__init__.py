"""HTTP routes: rendering, health and version, the web page, and the API docs pages."""

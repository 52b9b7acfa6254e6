"""The jinja2 templates, CSS and script of the HTML reports, shipped inside the package."""

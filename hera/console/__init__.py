"""The live web view of a running cluster (``hera view``, ``hera up --web``).

- :mod:`hera.console.buffers`: server-side downsampling of every stream;
- :mod:`hera.console.state`: what the view knows of the cluster (bus, liveliness, status);
- :mod:`hera.console.server`: the aiohttp server of the page and its JSON endpoint;
- ``static/``: the page, a plain HTML file and a script drawing on canvases (no build
  step, nothing loaded from the network).
"""

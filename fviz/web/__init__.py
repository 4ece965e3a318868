"""``fviz open FILE --web``: Rerun's viewer in the browser, with clicks (see ``docs/interactive.md``).

The page hosts the viewer that ``rerun-notebook`` ships (``widget.js``, an anywidget module, and
``re_viewer_bg.wasm``: the same version as the SDK) with a small stand-in for the anywidget model
(``page.html``). fviz serves the page and those files over HTTP on ``web_port`` and talks to it over a
WebSocket on ``port``: it sends the recording's bytes (and a blueprint's), receives the viewer's events
(JSON, as the notebook gets them) and answers a click with the bytes of its lines (:mod:`fviz.interactive`).
Both servers run in fviz's own process, bound to 127.0.0.1 unless asked otherwise: they die with it.
"""

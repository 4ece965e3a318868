"""``fviz open FILE --web``: Rerun's viewer in the browser, with clicks (see ``docs/interactive.md``).

The page hosts the viewer that ``rerun-notebook`` ships (``widget.js``, an anywidget module, and
``re_viewer_bg.wasm``: the same version as the SDK) with a small stand-in for the anywidget model
(``page.html``). fviz serves the page, those files and a WebSocket on one port (``web_port``,
:mod:`fviz.web.server`): it sends the recording's bytes (and a blueprint's) to a page holding the URL's secret
token, receives the viewer's events (JSON, as the notebook gets them) and answers a click with the bytes of its
lines (:mod:`fviz.interactive`). The server runs in fviz's own process, bound to 127.0.0.1 unless asked
otherwise: it dies with it.
"""

"""Rerun's private names, in one place: the only module that reaches past rerun's public API.

Two things fviz needs have no public name in rerun 0.41: parsing the JSON string the viewer widget sends for an
event (``rerun._event._viewer_event_from_json_str``: the click server and ``fviz.notebook`` receive the raw JSON)
and sending a recording's bytes to a notebook viewer (``Viewer._viewer.send_rrd``). Each is used through this
module, which first checks that the installed rerun is the version whose private names these are
(:data:`SUPPORTED`): another version is a one-line :class:`fviz.errors.FvizError` naming it, not an
``AttributeError`` deep in rerun. rerun is imported inside the functions (``fviz --help`` stays instant).
"""

from __future__ import annotations

from fviz.errors import FvizError

SUPPORTED = "0.41"  # the rerun minor version whose private names are used below (pyproject: rerun-sdk==0.41.*)


def check_version(version: str | None = None) -> str:
    """The installed rerun's version (or ``version``), if it is :data:`SUPPORTED` (``0.41.*``); else FvizError."""
    if version is None:
        import rerun

        version = str(rerun.__version__)
    if version.split(".")[:2] != SUPPORTED.split("."):
        raise FvizError(f"rerun {version} is installed; fviz's viewer events need rerun {SUPPORTED}.* "
                        f"(pip install 'rerun-sdk[notebook]=={SUPPORTED}.*')")
    return version


def viewer_event_from_json(text: str):
    """The JSON string the viewer widget sends for an event -> rerun's ``ViewerEvent`` (e.g. a
    ``SelectionChangeEvent``); ValueError or KeyError for a string that is not one."""
    check_version()
    from rerun._event import _viewer_event_from_json_str

    return _viewer_event_from_json_str(text)


def send_rrd(viewer, data: bytes) -> None:
    """Send a recording's bytes (an .rrd file's) to a ``rerun.notebook.Viewer``: the widget's own message for them."""
    check_version()
    viewer._viewer.send_rrd(data)

"""fviz: interactive visual debugging of fundamental-matrix estimation (KITTI, Rerun)."""

__version__ = "0.1.0"

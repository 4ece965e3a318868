"""User estimators that misbehave, for the isolation tests (``-e misbehaving_estimators:NAME``, on PYTHONPATH)."""

import sys
import threading

import cv2


def eight(pair, x_a, x_b):
    F, _ = cv2.findFundamentalMat(x_a, x_b, cv2.FM_8POINT)
    return F


def chatty(pair, x_a, x_b):
    print("chatty estimator says hello")
    return eight(pair, x_a, x_b)


def exits(pair, x_a, x_b):
    sys.exit(3)


def interrupts(pair, x_a, x_b):
    raise KeyboardInterrupt


def vandal(pair, x_a, x_b):
    """Zeroes its inputs in place: the matches and the images."""
    x_a[:] = 0
    x_b[:] = 0
    pair.image_a[:] = 0
    return None


def hangs(pair, x_a, x_b):
    threading.Event().wait()  # forever


def grad_tensor(pair, x_a, x_b):
    """8-point's F as a torch tensor that requires grad (a network's raw output)."""
    import torch

    return torch.tensor(eight(pair, x_a, x_b), requires_grad=True) * 1.0


class _Unconvertible:
    def __array__(self, *args, **kwargs):
        raise RuntimeError("this array-like refuses to convert")


def unconvertible(pair, x_a, x_b):
    return _Unconvertible()


def complex_f(pair, x_a, x_b):
    return eight(pair, x_a, x_b) + 1e-3j


def short_mask(pair, x_a, x_b):
    import numpy as np

    return eight(pair, x_a, x_b), np.ones(len(x_a) - 1, bool)

"""User estimators that misbehave, for the isolation tests (``-e trust_estimators:NAME``, on PYTHONPATH)."""

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

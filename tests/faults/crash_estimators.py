"""A user estimator that crashes the process it runs in (a segfault in native code), on synthetic seed 1
only; elsewhere OpenCV's 8-point F. ``-e tests/faults/crash_estimators.py:segfault_on_1``."""

import os
import signal


def segfault_on_1(pair, x_a, x_b):
    import cv2

    if pair.id.sequence == "1":
        os.kill(os.getpid(), signal.SIGSEGV)
    F, _ = cv2.findFundamentalMat(x_a, x_b, cv2.FM_8POINT)
    return F

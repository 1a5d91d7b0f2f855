"""Cameras tracked in a process of their own: :class:`TrackingProcess`.

The live loop tracks every frame while the smoother works on earlier ones. In threads of one
process the two contend for Python's interpreter lock: each call into OpenCV releases it and
must take it back, and the smoother's Python code holds it most of the time, so tracking three
cameras took 27 ms a frame at the median and 101 ms at the 95th percentile under the smoother's
load, against 22 ms of work. A process of its own has its own interpreter and, on a machine of
two cores, a core of its own. Each frame's images go to it over a pipe (pickled: grey
640x480 images are 0.3 MB each) and the tracks come back; a wrong image raises its
``ValueError`` in the caller, as :meth:`~apcc_graph.frontend.tracking.KLTTracker.update` would.

The process is a fresh interpreter running this module (``python -m``: it imports only the
tracker and OpenCV, about 0.5 s): the same on every platform, it inherits no threads or locks of
the caller and, unlike ``multiprocessing``'s spawn, never imports the caller's main script.
Messages are pickled over its standard input and output.
"""

from __future__ import annotations

import pickle
import subprocess
import sys
from typing import IO, Any

import numpy as np
from numpy.typing import NDArray

from apcc_graph.frontend.tracking import KLTTracker, TrackerOptions, gray_image

Tracks = dict[int, tuple[NDArray, NDArray]]
"""Camera -> its track ids ``(n,)`` and pixels ``(n, 2)``."""


def _serve(inbox: IO[bytes], outbox: IO[bytes]) -> None:
    """The process: the first message is ``(sizes, options)``, a tracker per camera; each
    next one ``camera -> image`` is answered with ``("ok", tracks)`` or ``("error",
    exception)``; ``None`` or the end of the input ends it."""
    sizes, options = pickle.load(inbox)
    trackers = {cam: KLTTracker(size, options) for cam, size in sizes.items()}
    while True:
        try:
            images = pickle.load(inbox)
        except EOFError:
            return
        if images is None:
            return
        try:
            answer: tuple[str, Any] = ("ok", {cam: trackers[cam].update(image)
                                              for cam, image in images.items()})
        except Exception as error:  # noqa: BLE001 (given to the caller, raised there)
            answer = ("error", error)
        pickle.dump(answer, outbox, protocol=pickle.HIGHEST_PROTOCOL)
        outbox.flush()


def end_process(process: subprocess.Popen, timeout: float) -> None:
    """End a child that stops when its input closes: close its input, wait ``timeout``
    seconds for it, then kill it, and close its output."""
    try:
        if process.stdin is not None:
            process.stdin.close()
    except (BrokenPipeError, OSError):
        pass
    try:
        process.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()
    if process.stdout is not None:
        process.stdout.close()


class TrackingProcess:
    """A :class:`~apcc_graph.frontend.tracking.KLTTracker` per camera, in a process of its own
    (module docstring); :meth:`track` with each frame's images, in order; :meth:`close` ends
    the process (also a context manager).

    Args:
        sizes: camera -> ``(width, height)`` its images must have.
        options: the trackers' parameters.
    """

    def __init__(self, sizes: dict[int, tuple[int, int]],
                 options: TrackerOptions | None = None) -> None:
        self.sizes = dict(sizes)
        self._process = subprocess.Popen(
            [sys.executable, "-m", "apcc_graph.frontend.tracking_process"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        self.frames = 0
        self._send((self.sizes, options))

    def track(self, images: dict[int, NDArray]) -> Tracks:
        """Each camera's live track ids and pixels in its new image (colour images are made
        grey here, so a third of the bytes cross the pipe).

        Raises:
            ValueError: an image of the wrong size or layout (the message names the frame).
            RuntimeError: the process ended.
        """
        grey = {cam: gray_image(image, None, f"frame {self.frames}")
                for cam, image in images.items()}
        try:
            self._send(grey)
            assert self._process.stdout is not None
            status, answer = pickle.load(self._process.stdout)
        except (EOFError, BrokenPipeError, OSError) as error:
            raise RuntimeError(f"the tracking process ended (exit code "
                               f"{self._process.poll()}) at frame {self.frames}") from error
        self.frames += 1
        if status == "error":
            raise answer
        return {cam: (np.asarray(ids), np.asarray(uv)) for cam, (ids, uv) in answer.items()}

    def _send(self, message: object) -> None:
        assert self._process.stdin is not None
        pickle.dump(message, self._process.stdin, protocol=pickle.HIGHEST_PROTOCOL)
        self._process.stdin.flush()

    def close(self) -> None:
        """End the process (waits a second for it, then kills it)."""
        try:
            self._send(None)
        except (BrokenPipeError, OSError, ValueError):
            pass
        end_process(self._process, 1.0)

    def __enter__(self) -> TrackingProcess:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


if __name__ == "__main__":  # the process (module docstring); prints go to stderr
    _inbox, _outbox = sys.stdin.buffer, sys.stdout.buffer
    sys.stdout = sys.stderr
    _serve(_inbox, _outbox)

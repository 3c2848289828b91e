"""What every process the learner starts on this machine (the rollout workers, the inference server) does about its
life: it dies with the learner, and a failure it reports is one line."""
from __future__ import annotations

import ctypes
import signal


def one_line(error: BaseException) -> str:
    text = " ".join(str(error).split()) or type(error).__name__
    return f"{type(error).__name__}: {text}"


def die_with_parent() -> None:
    """SIGKILL this process when the process that started it dies (Linux; elsewhere the pipe's end-of-file stops
    it at its next message), and leave Ctrl-C to the learner, which stops its children itself."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL)          # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
    signal.signal(signal.SIGINT, signal.SIG_IGN)

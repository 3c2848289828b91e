"""``torch_compile: true``: the learner's hot functions compiled with ``torch.compile`` (inductor, C++ on the CPU),
for this process only — the per-class embedding block and the Recurrent Temporal Attention, where most of a
forward/backward's small operations are (docs/benchmarks.md, "The learner against its FLOP limit").

Why these two and not the whole loss: the agent reads data-dependent sizes into Python (rows per class, slots used
per bucket), so a compiled loss breaks into many graphs and recompiles as the sizes move; these two functions take
tensors of symbolic size (``dynamic=True``) and compile once. The classes' methods are replaced in this process
(the rollout workers are other processes and stay eager), and ``restore`` puts the originals back, as the ONNX
export needs. If compiling or a compiled call fails, the original is put back for good and a warning says why:
the run goes on in eager mode.
"""
from __future__ import annotations

import warnings
from typing import Any, Callable


_PATCHED: dict[tuple[type, str], Callable[..., Any]] = {}


def _targets() -> list[tuple[type, str]]:
    from dynenv_ros.agent.network import EmbedBlock, RecurrentTemporalAttention
    return [(EmbedBlock, "forward"), (RecurrentTemporalAttention, "frames_first")]


def compile_hot_paths() -> bool:
    """Replace the hot methods with compiled ones (idempotent); False when torch cannot compile here."""
    if _PATCHED:
        return True
    try:
        import torch._dynamo  # noqa: F401 - fails on builds without the compiler stack
    except Exception as error:                   # pragma: no cover - depends on the torch build
        warnings.warn(f"torch_compile: torch cannot compile here ({error}); running eager", RuntimeWarning, stacklevel=1)
        return False
    for owner, name in _targets():
        original = getattr(owner, name)
        compiled = torch.compile(original, dynamic=True)

        def guarded(*args: Any, _compiled: Any = compiled, _original: Any = original, _owner: type = owner,
                    _name: str = name, **kwargs: Any) -> Any:
            try:
                return _compiled(*args, **kwargs)
            except Exception as error:           # a backend failure (no compiler, an unsupported op): eager for good
                warnings.warn(f"torch_compile: {_owner.__name__}.{_name} fell back to eager: "
                              f"{type(error).__name__}: {str(error).splitlines()[0] if str(error) else ''}",
                              RuntimeWarning, stacklevel=1)
                setattr(_owner, _name, _original)
                _PATCHED.pop((_owner, _name), None)
                return _original(*args, **kwargs)

        _PATCHED[(owner, name)] = original
        setattr(owner, name, guarded)
    return True


def restore() -> None:
    """The eager methods back (before an ONNX export, or when the run ends)."""
    for (owner, name), original in list(_PATCHED.items()):
        setattr(owner, name, original)
    _PATCHED.clear()


def compiled() -> bool:
    return bool(_PATCHED)

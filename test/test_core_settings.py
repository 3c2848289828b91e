"""What core/ writes once for the packages above it: settings dataclasses built from plain values (soccer's and
driving's configs use it) and numpy arrays in shared memory (the vector env's workers, the learner's rollout slots
and weights)."""
from __future__ import annotations

from dataclasses import dataclass, field
from multiprocessing import shared_memory

import numpy as np
import pytest

from dynenv_ros.core.settings import build_settings
from dynenv_ros.core.shared_arrays import SharedArrays, close_blocks


@dataclass(frozen=True)
class _Inner:
    speed: float = 1.0
    count: int = 2


@dataclass(frozen=True)
class _Outer:
    name: str = "x"
    on: bool = False
    inner: _Inner = field(default_factory=_Inner)


def test_nested_settings_are_built_and_each_value_checked_against_its_default():
    built = build_settings(_Outer, {"on": True, "inner": {"speed": 3, "count": 4}}, "test")
    assert built == _Outer("x", True, _Inner(3.0, 4)) and isinstance(built.inner.speed, float)
    for values, message in [({"speed": 1}, "unknown test setting(s): speed; known: name, on, inner"),
                            ({"inner": {"fast": 1}}, "unknown test setting(s): inner.fast; known: inner.speed, "
                                                     "inner.count"),
                            ({"inner": 3}, "inner must be a mapping of settings, got 3"),
                            ({"on": 1}, "on must be true or false, got 1"),
                            ({"inner": {"count": True}}, "inner.count must be an integer, got True"),
                            ({"inner": {"count": 2.0}}, "inner.count must be an integer, got 2.0"),
                            ({"inner": {"speed": "fast"}}, "inner.speed must be a number, got 'fast'"),
                            ({"name": 5}, "name must be a string, got 5")]:
        with pytest.raises(ValueError) as refused:
            build_settings(_Outer, values, "test")
        assert str(refused.value) == message


def test_shared_arrays_are_seen_by_name_and_unlinked_on_close():
    shared = SharedArrays({"a": ((2, 3), np.dtype(np.float32)), "b": ((4,), np.dtype(np.int64))})
    shared.arrays["a"][:] = 1.5
    names = shared.names()
    name, shape, dtype = names["a"]
    assert shape == (2, 3) and np.dtype(dtype) == np.float32
    attached = shared_memory.SharedMemory(name=name)
    view = np.ndarray(shape, np.dtype(dtype), buffer=attached.buf)
    assert (view == 1.5).all()
    del view
    close_blocks([attached])
    shared.close()
    with pytest.raises(FileNotFoundError):
        shared_memory.SharedMemory(name=name)
    shared.close()                                  # a second close does nothing

# numba ships no types; this stub declares the one function the project uses (mypy.ini: mypy_path). The kernels'
# own annotations are for mypy and the reader: numba types a kernel from the arguments of each call.
from collections.abc import Callable
from typing import Any, TypeVar

_F = TypeVar("_F", bound=Callable[..., Any])

def njit(*args: Any, **kwargs: Any) -> Callable[[_F], _F]: ...

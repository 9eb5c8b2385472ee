"""pycolmap's option objects configured from plain dicts (the ``sfm`` sub-sections)."""

from __future__ import annotations

from typing import Any


# ---- pycolmap option objects from dicts -------------------------------------------------------
def _option_names(obj: Any) -> list[str]:
    try:
        return sorted(obj.todict().keys())
    except (AttributeError, TypeError):
        return sorted(
            a for a in dir(obj) if not a.startswith("_") and not callable(getattr(obj, a))
        )


def _coerce(value: Any, current: Any, path: str) -> Any:
    """Make a config value fit the type of the option it sets: integral floats for integers, and
    strings of numbers or booleans (Snakemake's ``--config`` hands nested values as strings)."""
    if isinstance(value, str) and isinstance(current, bool):
        low = value.strip().lower()
        if low in ("true", "yes", "1", "false", "no", "0"):
            return low in ("true", "yes", "1")
    elif isinstance(value, str) and isinstance(current, int | float):
        try:
            value = float(value) if isinstance(current, float) else int(value)
        except ValueError:
            try:
                value = float(value)
            except ValueError:
                return value  # left to setattr's error
    if isinstance(current, int) and not isinstance(current, bool) and isinstance(value, float):
        if not value.is_integer():
            raise ValueError(f"config key '{path}': expected an integer, got {value}")
        return int(value)
    if isinstance(current, set) and isinstance(value, list):
        return set(value)
    return value


def set_options(obj: Any, values: dict[str, Any], where: str) -> Any:
    """Set attributes of a pycolmap options object from a (nested) dict; returns ``obj``.

    ``where`` is the config key path used in error messages (e.g. ``sfm.extraction``). Dotted keys
    (``sift.max_num_features``) and nested dicts reach sub-objects; strings name enum members;
    integral floats and strings of numbers are accepted for numeric options. Raises ``ValueError`` naming the key when the
    option does not exist or the value has the wrong type.
    """
    for key, value in (values or {}).items():
        head, _, rest = str(key).partition(".")
        path = f"{where}.{head}"
        names = _option_names(obj)
        if head not in names:
            raise ValueError(
                f"config key '{path}': pycolmap.{type(obj).__name__} has no option '{head}'; known options: {names}"
            )
        current = getattr(obj, head)
        if rest:
            value = {rest: value}
        if isinstance(value, dict):
            if not hasattr(current, "todict"):
                raise ValueError(
                    f"config key '{path}': option is a value ({current!r}), not a group of options"
                )
            set_options(current, value, path)
            continue
        if hasattr(type(current), "__members__") and isinstance(value, str):  # pybind11 enum
            members = type(current).__members__
            if value not in members:
                raise ValueError(f"config key '{path}': {value!r} is not one of {list(members)}")
            value = members[value]
        else:
            value = _coerce(value, current, path)
        try:
            setattr(obj, head, value)
        except (TypeError, ValueError) as e:
            raise ValueError(
                f"config key '{path}': cannot set {value!r} ({type(value).__name__}); expected "
                f"{type(current).__name__} like the default {current!r} ({type(e).__name__})"
            ) from None
    return obj

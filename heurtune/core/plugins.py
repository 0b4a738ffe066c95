"""User plugins: a ``.py`` file or an importable module that registers optimisers
(:func:`heurtune.core.registry.register`) or plant families
(:func:`heurtune.core.families.register_family`) when imported. No reinstall needed."""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import sys
from pathlib import Path

from heurtune.core.errors import ConfigError

__all__ = ["load_plugin", "load_plugins", "loaded"]

_LOADED_FILES: dict = {}  # resolved path -> module name
_MODULES: dict = {}  # module-name plugins (ordered set)


def load_plugin(spec: str):
    """Import a plugin: a path to a ``.py`` file or a module name (each file once per process).

    A file is imported under the name ``heurtune_plugin_<stem>_<hash of its path>``, the same in
    every process: workers load it under that name before they unpickle anything, and numba's
    on-disk cache (``cache=True``) finds the module of a cached kernel by that name. Load a
    plugin file only through this function (not also with ``importlib`` under another name).

    Parameters
    ----------
    spec : str
        A path to a ``.py`` file, or a module name.

    Returns
    -------
    module
        The plugin's module.

    Raises
    ------
    ConfigError
        For a file that does not exist or a module that cannot be imported.
    """
    spec = str(spec)
    if spec.endswith(".py"):
        path = Path(spec).resolve()
        if not path.is_file():
            raise ConfigError(f"plugin file {spec!r} does not exist")
        if path in _LOADED_FILES:
            return sys.modules[_LOADED_FILES[path]]
        # The same name in every process (workers load the file under it too), so that objects
        # of the plugin's classes pickle by reference.
        digest = hashlib.sha256(str(path).encode()).hexdigest()[:8]
        module_name = f"heurtune_plugin_{path.stem}_{digest}"
        mod_spec = importlib.util.spec_from_file_location(module_name, path)
        module = importlib.util.module_from_spec(mod_spec)
        sys.modules[module_name] = module
        _LOADED_FILES[path] = module_name
        try:
            mod_spec.loader.exec_module(module)
        except Exception as exc:
            del _LOADED_FILES[path]
            sys.modules.pop(module_name, None)
            raise ConfigError(_import_failure(exc, path)) from None
        except BaseException:
            del _LOADED_FILES[path]
            sys.modules.pop(module_name, None)
            raise
        return module
    try:
        module = importlib.import_module(spec)
    except ImportError as exc:
        raise ConfigError(f"cannot import plugin module {spec!r}: {exc}") from None
    except Exception as exc:
        origin = getattr(importlib.util.find_spec(spec.split(".")[0]), "origin", None)
        raise ConfigError(f"plugin module {spec!r}: {_import_failure(exc, Path(origin) if origin else None)}") \
            from None
    _MODULES.setdefault(spec, None)
    return module


def _import_failure(exc: Exception, path) -> str:
    """One line for a plugin whose import raised: the file and line, and what went wrong.

    A syntax error names its own line; any other exception the plugin's line it came through
    (the last frame in the plugin's file), its type (unless a ConfigError or ValueError, whose
    message says it) and its message, e.g. ``walk.py:14: TypeError:
    ControllerStructure.__init__() missing 1 required positional argument: 'design'``."""
    if isinstance(exc, SyntaxError):
        name = Path(exc.filename).name if exc.filename else (path.name if path else "plugin")
        return f"{name}:{exc.lineno}: syntax error: {exc.msg}"
    line, name = None, path.name if path else "plugin"
    tb = exc.__traceback__
    while tb is not None:
        if path is not None and Path(tb.tb_frame.f_code.co_filename).resolve() == Path(path).resolve():
            line = tb.tb_lineno
        tb = tb.tb_next
    what = str(exc) if isinstance(exc, (ConfigError, ValueError)) and str(exc) else f"{type(exc).__name__}: {exc}"
    return f"{name}{f':{line}' if line else ''}: {what.splitlines()[0] if what else type(exc).__name__}"


def load_plugins(specs) -> None:
    """:func:`load_plugin` each of ``specs``.

    Parameters
    ----------
    specs : iterable of str
        A config's ``plugins`` list.
    """
    for spec in specs or ():
        load_plugin(spec)


def loaded() -> tuple:
    """The plugins loaded in this process.

    Returns
    -------
    tuple of str
        Resolved file paths and module names, in order (what a worker process loads before it
        unpickles anything).
    """
    return tuple(str(p) for p in _LOADED_FILES) + tuple(_MODULES)

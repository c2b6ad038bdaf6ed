"""A NumPy function called from compiled JAX programs as an XLA FFI custom call
(:func:`host_call`), so that those programs are kept in JAX's persistent compilation cache.

Why not ``jax.pure_callback``: JAX never writes a program that holds a Python host callback
to its persistent cache (``jax._src.compiler._cache_write``: "because it uses host
callbacks"), since the callback is a pointer into the process that compiled it. Every program
of the C MuJoCo engine (:mod:`galileo_jax.physics.simulate_c`) holds one, so every process
compiled all of them again: on README command 1's ``fit --method grad`` about 7 programs, and
on a ``diagnose`` run (a calibration video of ``ramp_20``, fresh process) about 280 s of
compilation of 1,270 s, most of it these. An FFI custom call is named, not pointed to: the
compiled program calls the target by its name, which the process that loads it from the cache
registers before it runs it (:func:`host_call` registers on first use, in every process).

How: the target is a C function pointer made by ``ctypes`` (``CFUNCTYPE``, which takes the
GIL, so XLA may call it from any of its threads) that reads XLA's FFI call frame (the C API
``xla/ffi/api/c_api.h`` shipped in jaxlib, ``jax.ffi.include_dir()``, API version 0.3:
``XLA_FFI_CallFrame``, ``XLA_FFI_Buffer``), copies its argument buffers into NumPy arrays,
calls the Python function and copies its result into the output buffer. It answers
XLA's metadata query (the API version it was written against) and reports a Python exception
as an FFI error, which JAX raises. Registered with ``jax.ffi.register_ffi_target``; called with
``jax.ffi.ffi_call`` (JAX documentation, "Foreign function interface (FFI)").

The target is registered for the CPU, where XLA hands it host memory. A program built for
another backend (a GPU: ``jax.default_backend()`` when it is traced) calls ``fn`` through
``jax.pure_callback`` instead, as before, and is compiled in every process.

A target's name must identify the function: a program loaded from the cache calls whatever
function is registered under its name in the loading process. :func:`host_call` callers build
the name from everything the function depends on (:func:`stable_name`).
"""

from __future__ import annotations

import ctypes
import hashlib
import threading
import traceback
from typing import Callable

import jax
import numpy as np

#: XLA FFI C API version this module reads (``XLA_FFI_API_MAJOR``, ``XLA_FFI_API_MINOR`` of
#: jaxlib's ``xla/ffi/api/c_api.h``).
FFI_API_VERSION = (0, 3)

_METADATA_EXTENSION = 1  # XLA_FFI_Extension_Metadata
_EXECUTE = 3  # XLA_FFI_ExecutionStage_EXECUTE
_ERROR_INTERNAL = 13  # XLA_FFI_Error_Code_INTERNAL
#: XLA_FFI_DataType codes of the dtypes a host function may take or return.
_DTYPES = {1: np.bool_, 4: np.int32, 5: np.int64, 11: np.float32, 12: np.float64}


class _ExtensionBase(ctypes.Structure):
    pass


_ExtensionBase._fields_ = [("struct_size", ctypes.c_size_t), ("type", ctypes.c_int),
                           ("next", ctypes.POINTER(_ExtensionBase))]


class _ApiVersion(ctypes.Structure):
    _fields_ = [("struct_size", ctypes.c_size_t), ("extension_start", ctypes.c_void_p),
                ("major_version", ctypes.c_int), ("minor_version", ctypes.c_int)]


class _Metadata(ctypes.Structure):
    _fields_ = [("struct_size", ctypes.c_size_t), ("api_version", _ApiVersion), ("traits", ctypes.c_uint32),
                ("state_type_id", ctypes.c_int64)]


class _MetadataExtension(ctypes.Structure):
    _fields_ = [("extension_base", _ExtensionBase), ("metadata", ctypes.POINTER(_Metadata))]


class _Buffer(ctypes.Structure):
    _fields_ = [("struct_size", ctypes.c_size_t), ("extension_start", ctypes.c_void_p), ("dtype", ctypes.c_int),
                ("data", ctypes.c_void_p), ("rank", ctypes.c_int64), ("dims", ctypes.POINTER(ctypes.c_int64))]


class _Operands(ctypes.Structure):  # XLA_FFI_Args and XLA_FFI_Rets have this layout
    _fields_ = [("struct_size", ctypes.c_size_t), ("extension_start", ctypes.c_void_p), ("size", ctypes.c_int64),
                ("types", ctypes.POINTER(ctypes.c_int)), ("ptrs", ctypes.POINTER(ctypes.c_void_p))]


class _Attrs(ctypes.Structure):
    _fields_ = [("struct_size", ctypes.c_size_t), ("extension_start", ctypes.c_void_p), ("size", ctypes.c_int64),
                ("types", ctypes.c_void_p), ("names", ctypes.c_void_p), ("attrs", ctypes.c_void_p)]


class _CallFrame(ctypes.Structure):
    _fields_ = [("struct_size", ctypes.c_size_t), ("extension_start", ctypes.POINTER(_ExtensionBase)),
                ("api", ctypes.c_void_p), ("ctx", ctypes.c_void_p), ("stage", ctypes.c_int), ("args", _Operands),
                ("rets", _Operands), ("attrs", _Attrs), ("future", ctypes.c_void_p)]


class _ErrorCreateArgs(ctypes.Structure):
    _fields_ = [("struct_size", ctypes.c_size_t), ("extension_start", ctypes.c_void_p), ("message", ctypes.c_char_p),
                ("errc", ctypes.c_int)]


_ErrorCreate = ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.POINTER(_ErrorCreateArgs))


class _Api(ctypes.Structure):  # the head of XLA_FFI_Api: XLA_FFI_Error_Create is its first function
    _fields_ = [("struct_size", ctypes.c_size_t), ("extension_start", ctypes.c_void_p), ("api_version", _ApiVersion),
                ("internal_api", ctypes.c_void_p), ("error_create", _ErrorCreate)]


_Handler = ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.POINTER(_CallFrame))

_FUNCTIONS: dict[str, Callable[..., np.ndarray]] = {}
_HANDLERS: dict[str, object] = {}  # the ctypes function objects, kept alive for the process
_LOCK = threading.Lock()


def stable_name(prefix: str, *parts) -> str:
    """A target name from ``prefix`` and a SHA-1 of ``repr(parts)``: the same in every process
    for the same parts (they must print the same: strings, numbers, tuples of them; no object
    addresses)."""
    digest = hashlib.sha1(repr(parts).encode()).hexdigest()[:24]
    return f"{prefix}_{digest}"


def _array(buffer: _Buffer) -> np.ndarray:
    """The FFI buffer as a NumPy array over its memory (no copy)."""
    dtype = np.dtype(_DTYPES[buffer.dtype])
    shape = tuple(buffer.dims[i] for i in range(buffer.rank))
    size = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    if size == 0:
        return np.zeros(shape, dtype)
    raw = (ctypes.c_char * size).from_address(buffer.data)
    return np.frombuffer(raw, dtype).reshape(shape)


def _error(frame: _CallFrame, message: str) -> int | None:
    api = ctypes.cast(frame.api, ctypes.POINTER(_Api)).contents
    args = _ErrorCreateArgs(ctypes.sizeof(_ErrorCreateArgs), None, message.encode()[:4000], _ERROR_INTERNAL)
    return api.error_create(ctypes.byref(args))


def _make_handler(name: str):
    def handler(frame_ptr):
        frame = frame_ptr.contents
        ext = frame.extension_start
        if ext and ext.contents.type == _METADATA_EXTENSION:  # XLA asks which API version this is
            meta = ctypes.cast(ext, ctypes.POINTER(_MetadataExtension)).contents.metadata.contents
            meta.api_version = _ApiVersion(ctypes.sizeof(_ApiVersion), None, *FFI_API_VERSION)
            meta.traits = 0
            return None
        if frame.stage != _EXECUTE:
            return None
        try:
            # copies: XLA may reuse the buffers after the call, and ``fn`` may keep what it gets
            args = [np.array(_array(ctypes.cast(frame.args.ptrs[i], ctypes.POINTER(_Buffer)).contents))
                    for i in range(frame.args.size)]
            out = _array(ctypes.cast(frame.rets.ptrs[0], ctypes.POINTER(_Buffer)).contents)
            result = np.asarray(_FUNCTIONS[name](*args))
            if result.shape != out.shape:
                raise ValueError(f"host function {name} returned shape {result.shape}, expected {out.shape}")
            out[...] = result
            return None
        except BaseException:  # noqa: BLE001 - reported to XLA, which makes JAX raise it
            return _error(frame, f"{name}: {traceback.format_exc()}")

    return _Handler(handler)


def host_call(name: str, fn: Callable[..., np.ndarray], result: jax.ShapeDtypeStruct, *args,
              vmap_method: str = "expand_dims") -> jax.Array:
    """``fn(*args)`` computed on the host from inside ``jit``, as ``jax.pure_callback`` does,
    but through the XLA FFI target ``name`` (module docstring): a program that calls it is
    stored in JAX's persistent compilation cache.

    Args:
        name: the target's name (:func:`stable_name`); the same name must always mean the same
            function, in every process. The latest ``fn`` given for a name is the one called.
        fn: NumPy function of the arguments' values (copies of XLA's buffers) returning one
            array of ``result``'s shape (with any batch axes vmap adds) and dtype.
        result: the output's shape and dtype (bool, int32, int64, float32 or float64).
        args: JAX arrays of those dtypes.
        vmap_method: as ``jax.ffi.ffi_call``'s (default: batched axes reach ``fn`` as leading
            axes, unbatched arguments with leading axes of size 1).

    Returns:
        the array ``fn`` computed.

    Raises:
        jax.errors.JaxRuntimeError (when the program runs): ``fn`` raised; its traceback is
            the message.
    """
    if jax.default_backend() != "cpu":  # a GPU's program would look for a GPU target of that name
        return jax.pure_callback(fn, result, *args, vmap_method=vmap_method)
    with _LOCK:
        _FUNCTIONS[name] = fn
        if name not in _HANDLERS:
            handler = _make_handler(name)
            jax.ffi.register_ffi_target(name, jax.ffi.pycapsule(handler), platform="cpu")
            _HANDLERS[name] = handler
    return jax.ffi.ffi_call(name, result, vmap_method=vmap_method)(*args)

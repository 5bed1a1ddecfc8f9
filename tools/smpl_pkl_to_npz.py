#!/usr/bin/python3
"""Convert an official SMPL model .pkl into the .npz that flsh loads (loadBodyModel).

The official SMPL files are Python 2 pickles holding chumpy arrays and a scipy.sparse
J_regressor. This script reads them WITHOUT chumpy (and without depending on the scipy
version): a restricted unpickler maps every chumpy class to a small stand-in that keeps the
pickled state (chumpy stores an array's value under 'x'), rebuilds scipy.sparse matrices
from their pickled arrays, and refuses any class outside numpy, scipy.sparse, chumpy and a
few builtins, so a pickle cannot run arbitrary code.

Output keys (SMPL's shapes; float64, integers as int64, the root's parent as -1):
  v_template (V, 3), shapedirs (V, 3, K), posedirs (V, 3, 9(J-1)), J_regressor (J, V) dense,
  weights (V, J), kintree_table (2, J), f (F, 3).

The output is written to a temporary file beside the target and renamed into place, so a
failure never leaves a partial file. Exit status: 0 on success, 1 on a bad input file,
2 on bad usage.
"""

import argparse
import os
import pickle
import sys
import tempfile

import numpy as np

SMPL_KEYS = ("v_template", "shapedirs", "posedirs", "J_regressor", "weights", "kintree_table", "f")

# Unsigned encodings of -1 (the root's parent) in kintree_table.
ROOT_PARENT_ENCODINGS = (-1, 2**32 - 1, 2**64 - 1)


class ConversionError(Exception):
    """A bad input file; the message names the file and the key."""


class _StateStandIn:
    """Base of the stand-ins: created without running the real class's code, keeps the pickled
    state in __dict__. Subclasses name the class they replace in `replaced_class`."""

    replaced_class = "?"

    def __new__(cls, *args, **kwargs):
        return object.__new__(cls)

    def __init__(self, *args, **kwargs):
        pass

    def __setstate__(self, state):
        # pickle passes __getstate__'s dict, or (dict, slots) for classes with __slots__.
        if isinstance(state, tuple) and len(state) == 2:
            merged = dict(state[0] or {})
            merged.update(state[1] or {})
            state = merged
        if not isinstance(state, dict):
            raise ConversionError("unexpected pickled state of %s: %r" % (self.replaced_class, type(state)))
        self.__dict__.update(state)


class ChumpyStandIn(_StateStandIn):
    """Replaces any chumpy class while unpickling: keeps the state, exposes the value 'x'."""

    replaced_class = "chumpy.ch.Ch"


class SparseStandIn(_StateStandIn):
    """Replaces a scipy.sparse matrix class: keeps its pickled arrays and densifies them
    itself, so old pickles (scipy 0.x attribute sets) load with any scipy, or none."""

    replaced_class = "scipy.sparse.csc_matrix"

    def toarray(self, what):
        state = self.__dict__
        shape = state.get("_shape", state.get("shape"))
        try:
            rows, cols = (int(n) for n in shape)
            data = np.asarray(state["data"], dtype=np.float64)
            dense = np.zeros((rows, cols))
            fmt = self.replaced_class.rsplit(".", 1)[-1][:3]
            if fmt in ("csc", "csr"):
                indices = np.asarray(state["indices"], dtype=np.int64)
                indptr = np.asarray(state["indptr"], dtype=np.int64)
                outer = np.repeat(np.arange(len(indptr) - 1), np.diff(indptr))
                if fmt == "csc":
                    np.add.at(dense, (indices, outer), data)
                else:
                    np.add.at(dense, (outer, indices), data)
            elif fmt == "coo":
                row = np.asarray(state["row"], dtype=np.int64)
                col = np.asarray(state["col"], dtype=np.int64)
                np.add.at(dense, (row, col), data)
            else:
                raise ConversionError("unsupported sparse format %s" % self.replaced_class)
        except ConversionError as error:
            raise ConversionError("%s: %s" % (what, error))
        except (KeyError, TypeError, ValueError, IndexError) as error:
            raise ConversionError("%s: malformed %s (%s: %s)"
                                  % (what, self.replaced_class, type(error).__name__, error))
        return dense


_SPARSE_CLASSES = ("csc_matrix", "csr_matrix", "coo_matrix", "csc_array", "csr_array",
                   "coo_array")

_stand_in_classes = {}


def stand_in_for(module, name):
    """One stand-in subclass per chumpy class, so messages can name the original class."""
    key = module + "." + name
    if key not in _stand_in_classes:
        _stand_in_classes[key] = type(name, (ChumpyStandIn,), {"replaced_class": key})
    return _stand_in_classes[key]


# Builtins that Python 2 pickles of numpy/scipy/chumpy objects refer to (and nothing that
# can run code, such as eval or getattr).
_SAFE_BUILTINS = {"object", "set", "frozenset", "list", "dict", "tuple", "int", "float",
                  "complex", "str", "bytes", "bytearray", "bool", "slice", "range", "unicode",
                  "long"}


# What pickled numpy arrays, dtypes and scalars refer to (any Python and numpy version).
_NUMPY_NAMES = {"_reconstruct", "scalar", "ndarray", "dtype", "_frombuffer"}


class SmplUnpickler(pickle.Unpickler):
    def find_class(self, module, name):
        if module == "chumpy" or module.startswith("chumpy."):
            return stand_in_for(module, name)
        if module in ("copy_reg", "copyreg") and name == "_reconstructor":
            return super().find_class(module, name)
        if module == "_codecs" and name == "encode":  # how Python 3 pickles bytes (protocol < 3)
            return super().find_class(module, name)
        if module in ("__builtin__", "builtins") and name in _SAFE_BUILTINS:
            return super().find_class(module, name)
        if module.startswith("scipy.sparse") and name in _SPARSE_CLASSES:
            key = module + "." + name
            if key not in _stand_in_classes:
                _stand_in_classes[key] = type(name, (SparseStandIn,), {"replaced_class": key})
            return _stand_in_classes[key]
        if (module == "numpy" or module.startswith("numpy.")) and name in _NUMPY_NAMES:
            return super().find_class(module, name)
        raise ConversionError("refusing to unpickle %s.%s (only numpy arrays, scipy.sparse "
                              "matrices and chumpy objects belong in an SMPL model file)"
                              % (module, name))


def to_array(value, what):
    """numpy array of a pickled value: chumpy stand-ins give their 'x', sparse becomes dense."""
    seen = 0
    while isinstance(value, ChumpyStandIn):
        if "x" not in value.__dict__:
            raise ConversionError("%s is a chumpy expression (%s) without a stored value 'x'"
                                  % (what, value.replaced_class))
        value = value.__dict__["x"]
        seen += 1
        if seen > 100:
            raise ConversionError("%s: chumpy values nest too deeply" % what)
    if isinstance(value, SparseStandIn):
        value = value.toarray(what)
    try:
        array = np.asarray(value)
    except Exception as error:  # noqa: BLE001 - any failure is a bad file
        raise ConversionError("%s cannot be read as an array: %s" % (what, error))
    if array.dtype == object:
        raise ConversionError("%s holds Python objects, not numbers" % what)
    return array


def as_float64(array, what):
    if not (np.issubdtype(array.dtype, np.number) or array.dtype == bool):
        raise ConversionError("%s: expected numbers, got dtype %s" % (what, array.dtype))
    out = array.astype(np.float64)
    if not np.all(np.isfinite(out)):
        raise ConversionError("%s contains NaN or Inf" % what)
    return out


def as_int64(array, what, root_parent=False):
    if np.issubdtype(array.dtype, np.floating):
        if not np.all(np.isfinite(array)) or np.any(array != np.round(array)):
            raise ConversionError("%s: expected integer values" % what)
        array = array.astype(np.int64)
    elif not np.issubdtype(array.dtype, np.integer):
        raise ConversionError("%s: expected integers, got dtype %s" % (what, array.dtype))
    if root_parent:
        array = array.astype(object)  # exact comparison with 2**64-1 for uint64 input
        array[0, :] = [-1 if int(p) in ROOT_PARENT_ENCODINGS else int(p) for p in array[0, :]]
    return np.asarray(array, dtype=np.int64)


def expect_shape(array, shape, what):
    """shape: tuple of ints or None (any extent)."""
    ok = array.ndim == len(shape) and all(e is None or e == a for e, a in zip(shape, array.shape))
    if not ok:
        text = "(" + ", ".join("*" if e is None else str(e) for e in shape) + ")"
        raise ConversionError("%s: expected shape %s, got %s" % (what, text, tuple(array.shape)))


def load_pkl(path):
    try:
        with open(path, "rb") as handle:
            data = SmplUnpickler(handle, encoding="latin1").load()
    except ConversionError as error:
        raise ConversionError("%s: %s" % (path, error))
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError, ImportError,
            IndexError, KeyError, MemoryError) as error:
        raise ConversionError("%s: not a readable SMPL pickle (%s: %s)"
                              % (path, type(error).__name__, error))
    if not isinstance(data, dict):
        raise ConversionError("%s: expected a pickled dict of SMPL arrays, got %s"
                              % (path, type(data).__name__))
    return data


def convert(data, path):
    """The SMPL arrays of an unpickled model dict, checked against each other."""
    missing = [k for k in SMPL_KEYS if k not in data]
    if missing:
        raise ConversionError("%s: missing key(s) %s (keys present: %s)"
                              % (path, ", ".join(missing), ", ".join(sorted(map(str, data)))))

    def key(name):
        return "%s: key '%s'" % (path, name)

    raw = {k: to_array(data[k], key(k)) for k in SMPL_KEYS}
    out = {}
    out["v_template"] = as_float64(raw["v_template"], key("v_template"))
    expect_shape(out["v_template"], (None, 3), key("v_template"))
    V = out["v_template"].shape[0]

    tree = as_int64(raw["kintree_table"], key("kintree_table"), root_parent=raw["kintree_table"].ndim == 2)
    expect_shape(tree, (2, None), key("kintree_table"))
    J = tree.shape[1]
    parents = tree[0]
    if J < 1 or parents[0] != -1 or any(not (0 <= parents[j] < j) for j in range(1, J)):
        raise ConversionError("%s: row 0 must list parents with the root first (-1) and "
                              "parent[j] < j, got %s" % (key("kintree_table"), parents.tolist()))
    out["kintree_table"] = tree

    out["shapedirs"] = as_float64(raw["shapedirs"], key("shapedirs"))
    expect_shape(out["shapedirs"], (V, 3, None), key("shapedirs") + " (V from v_template)")
    out["posedirs"] = as_float64(raw["posedirs"], key("posedirs"))
    expect_shape(out["posedirs"], (V, 3, 9 * (J - 1)),
                 key("posedirs") + " (V from v_template, 9(J-1) from kintree_table)")
    out["J_regressor"] = as_float64(raw["J_regressor"], key("J_regressor"))
    expect_shape(out["J_regressor"], (J, V), key("J_regressor") + " (J from kintree_table)")
    out["weights"] = as_float64(raw["weights"], key("weights"))
    expect_shape(out["weights"], (V, J), key("weights"))

    faces = as_int64(raw["f"], key("f"))
    expect_shape(faces, (None, 3), key("f"))
    if faces.size and (faces.min() < 0 or faces.max() >= V):
        raise ConversionError("%s: vertex indices must lie in [0, %d], found %d..%d"
                              % (key("f"), V - 1, faces.min(), faces.max()))
    out["f"] = faces
    return out


def write_npz_atomically(arrays, target):
    directory = os.path.dirname(os.path.abspath(target))
    handle = tempfile.NamedTemporaryFile(dir=directory, prefix="." + os.path.basename(target) + ".",
                                         suffix=".tmp", delete=False)
    try:
        with handle:
            np.savez(handle, **arrays)
        os.replace(handle.name, target)
    except BaseException:
        try:
            os.unlink(handle.name)
        except OSError:
            pass
        raise


def main(argv=None):
    parser = argparse.ArgumentParser(
        prog="smpl_pkl_to_npz.py",
        description="Convert an official SMPL model .pkl (chumpy arrays, scipy.sparse "
                    "J_regressor) to the .npz flsh loads. chumpy is not needed.",
        epilog="Example: smpl_pkl_to_npz.py basicModel_f_lbs_10_207_0_v1.0.0.pkl smpl_female.npz")
    parser.add_argument("input", help="SMPL model .pkl")
    parser.add_argument("output", nargs="?",
                        help="output .npz (default: the input path with the extension .npz)")
    args = parser.parse_args(argv)
    output = args.output or os.path.splitext(args.input)[0] + ".npz"
    try:
        if not os.path.isfile(args.input):
            raise ConversionError("%s: no such file" % args.input)
        arrays = convert(load_pkl(args.input), args.input)
        out_dir = os.path.dirname(os.path.abspath(output))
        if not os.path.isdir(out_dir):
            raise ConversionError("%s: output directory %s does not exist" % (output, out_dir))
        write_npz_atomically(arrays, output)
    except ConversionError as error:
        print("smpl_pkl_to_npz: error: %s" % error, file=sys.stderr)
        return 1
    except OSError as error:
        print("smpl_pkl_to_npz: error: %s" % error, file=sys.stderr)
        return 1
    V, J = arrays["weights"].shape
    print("wrote %s: V=%d vertices, F=%d faces, J=%d joints, K=%d shape components (from %s)"
          % (output, V, arrays["f"].shape[0], J, arrays["shapedirs"].shape[2], args.input))
    return 0


if __name__ == "__main__":
    sys.exit(main())

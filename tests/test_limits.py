"""Memory is checked before allocation wherever a size comes from input: n_h, chain and
block sizes, a delay or look-ahead in samples, regression rows, MAT dimensions (a
look-ahead longer than the record of a whole-record inversion is the whole record, and
allocates nothing of its size), arrays nested in a MAT file's structs and cell arrays,
compressed MAT elements that inflate past the cap (zip bombs). Each
case runs in a child process whose address space is capped (RLIMIT_AS) at its start
plus 1 GiB: a size past the documented cap must be refused with a ValueError naming
the argument before anything is allocated; an attempt to allocate it would kill the
child (Rust aborts on a failed allocation) or raise MemoryError, and fail the test."""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

resource = pytest.importorskip("resource")

CHILD = textwrap.dedent(r"""
    import io, json, resource, struct, sys, tempfile, os, zlib
    import numpy as np
    import preisach
    import preisach.matlab
    from preisach import _preisach
    from preisach.sim import Stage

    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    with open("/proc/self/status") as f:
        vm = next(int(l.split()[1]) * 1024 for l in f if l.startswith("VmSize"))
    resource.setrlimit(resource.RLIMIT_AS, (vm + 2**30, hard))

    u = 5.0 + 4.0 * np.sin(np.arange(2000) / 30.0)
    y = np.tanh(u - 5.0)
    hyst = next(b for b in Stage.preset("paper").blocks if b["type"] == "hysteresis")
    noise = np.random.default_rng(0).uniform(0.0, 10.0, 20_000)
    model = preisach.PreisachModel(np.triu(np.full((8, 8), 0.1)), (0.0, 10.0))
    d = tempfile.mkdtemp()

    def mat_with_dims(rows, cols):
        # A MAT v5 file whose one double matrix declares rows x cols but holds 8 bytes.
        head = b"MATLAB 5.0 MAT-file".ljust(116, b" ") + b"\0" * 8 + struct.pack("<HH", 0x0100, 0x4D49)
        name = b"u_dac".ljust(8, b"\0")
        nbytes = rows * cols * 8
        body = (struct.pack("<II", 6, 8) + struct.pack("<II", 6, 0)            # array flags: double
                + struct.pack("<II", 5, 8) + struct.pack("<ii", rows, cols)      # dimensions
                + struct.pack("<II", 1, 5) + name                                # name
                + struct.pack("<II", 9, nbytes % 2**32) + b"\0" * 8)             # data (truncated)
        p = os.path.join(d, f"m{rows}x{cols}.mat")
        with open(p, "wb") as f:
            f.write(head + struct.pack("<II", 14, len(body)) + body)
        return p

    def el(kind, data, declared=None):
        # One v5 data element: tag (type, byte count) and its data, padded to 8 bytes.
        n = len(data) if declared is None else declared
        return struct.pack("<II", kind, n) + data + b"\0" * (-len(data) % 8)

    def matrix_head(cls, dims, name, nbytes):
        # The start of an miMATRIX element of nbytes bytes: flags, dimensions, name.
        head = el(6, struct.pack("<II", cls, 0)) + el(5, struct.pack(f"<{len(dims)}i", *dims)) + el(1, name)
        return struct.pack("<II", 14, nbytes) + head, len(head)

    def matrix(cls, dims, name, body=b""):
        head, n = matrix_head(cls, dims, name, 0)
        return struct.pack("<II", 14, n + len(body)) + head[8:] + body

    def fields(*names):
        return el(5, struct.pack("<i", 32)) + el(1, b"".join(f.ljust(32, b"\0") for f in names))

    def deflate(*parts):
        # A zlib stream of parts: bytes, or an int k for k MiB of zeros (each MiB the same
        # full-flushed block, so a GiB costs a few KB and no GiB is ever held).
        c, out, adler, zeros = zlib.compressobj(9), [], 1, bytes(2**20)
        for part in parts:
            if isinstance(part, bytes):
                out.append(c.compress(part) + c.flush(zlib.Z_FULL_FLUSH))
                adler = zlib.adler32(part, adler)
            else:
                block = c.compress(zeros) + c.flush(zlib.Z_FULL_FLUSH)
                out += [block] * part
                for _ in range(part):
                    adler = zlib.adler32(zeros, adler)
        return b"".join(out) + b"\x03\x00" + struct.pack(">I", adler)

    def mat_file(name, *elements):
        head = b"MATLAB 5.0 MAT-file".ljust(116, b" ") + b"\0" * 8 + struct.pack("<HH", 0x0100, 0x4D49)
        p = os.path.join(d, name)
        with open(p, "wb") as f:
            f.write(head + b"".join(elements))
        return p

    def nested_struct():
        # s.inner: a struct array that declares 2^16 x 2^16 elements (and holds none):
        # read as declared, 32 GiB of object pointers.
        inner = matrix(2, (2**16, 2**16), b"", fields(b"a"))
        return mat_file("nested.mat", matrix(2, (1, 1), b"s", fields(b"inner") + inner))

    def nested_cell():
        # c{1}: a char array of 1 x 2^31-1 without data, in a cell array, in a compressed
        # element: read as declared, 8 GiB of blanks.
        inner = matrix(4, (1, 2**31 - 1), b"", el(16, b""))
        z = deflate(matrix(1, (1, 1), b"c", inner))
        return mat_file("cell.mat", struct.pack("<II", 15, len(z)) + z)

    def zip_bomb(mib, cls):
        # A compressed struct "capture" with fields a and b, each 1 x mib MiB of zeros of
        # class cls (uint8: 9, double: 6): a few KB on disk.
        n = mib * 2**20
        values = n if cls == 9 else n // 8
        field_head, fh = matrix_head(cls, (1, values), b"", 0)
        data_tag = struct.pack("<II", 2 if cls == 9 else 9, n)
        field_bytes = fh + 8 + n
        field_head = struct.pack("<II", 14, field_bytes) + field_head[8:]
        head, hn = matrix_head(2, (1, 1), b"capture", 0)
        names = fields(b"a", b"b")
        total = hn + len(names) + 2 * (8 + field_bytes)
        head = struct.pack("<II", 14, total) + head[8:] + names
        z = deflate(head, field_head + data_tag, mib, field_head + data_tag, mib)
        return mat_file(f"bomb{mib}.mat", struct.pack("<II", 15, len(z)) + z)

    CASES = {
        "fit n_h": (lambda: preisach.PreisachModel.fit(u, y, n_h=10**6), "n_h"),
        "fit n_h cap+1": (lambda: preisach.PreisachModel.fit(u, y, n_h=16_001), "n_h"),
        "fit n_h 2^40": (lambda: preisach.PreisachModel.fit(u, y, n_h=2**40), "n_h"),
        "fit n_h 2^40 in a range": (lambda: preisach.PreisachModel.fit(u, y, n_h=2**40, u_range=(0.0, 10.0)), "n_h"),
        "preset n_h": (lambda: Stage.preset("paper", n_h=10**6), "n_h"),
        "json hysteresis n_h": (lambda: preisach.Chain.from_blocks([dict(hyst, n_h=10**7)]), "n_h"),
        "delay samples": (lambda: preisach.Chain.from_blocks([{"type": "delay", "delay_s": 1e6}],
                                                             sample_rate_hz=1e5).run(u), "delay_s"),
        "delay on a record": (lambda: preisach.Chain.from_blocks([{"type": "delay", "delay_s": 1e4}]).predict(
            np.arange(10) * 1e-6, np.zeros(10)), "delay_s"),
        "lookahead stream": (lambda: model.inverter("interpolated", lookahead=2**40), "lookahead"),
        "lookahead invert": (lambda: model.invert(u, "interpolated", lookahead=2**40), None),
        "regression rows": (lambda: _preisach.regression_rows(noise, noise, 600, (0.0, 10.0)),
                            "n_h"),
        "MAT dimensions": (lambda: preisach.matlab.read_mat(mat_with_dims(2**20, 2**12), u="u_dac", fs=1e3),
                           "u_dac"),
        "MAT dimensions list": (lambda: preisach.matlab.list_channels(mat_with_dims(2**30, 2**10)), ".mat"),
        "MAT nested struct": (lambda: preisach.matlab.list_channels(nested_struct()), "nested.mat: variable s"),
        "MAT nested cell": (lambda: preisach.matlab.list_channels(nested_cell()), "cell.mat: variable c"),
        "MAT zip bomb": (lambda: preisach.matlab.list_channels(zip_bomb(65, 9)), "bomb65.mat: variable capture"),
        "MAT zip bomb 1 GiB": (lambda: preisach.matlab.read_mat(zip_bomb(600, 6), u="a", fs=1e3),
                               "bomb600.mat: variable capture"),
    }
    name = sys.argv[1]
    call, arg = CASES[name]
    try:
        call()
    except ValueError as exc:
        assert arg is not None and arg in str(exc), f"{name}: the error does not name {arg}: {exc}"
        print("refused:", exc)
    else:
        if arg is not None:
            raise SystemExit(f"{name}: accepted")
        print("refused: nothing to refuse, and nothing of that size allocated")
""")

NAMES = ["fit n_h", "fit n_h cap+1", "fit n_h 2^40", "fit n_h 2^40 in a range", "preset n_h", "json hysteresis n_h", "delay samples",
         "delay on a record", "lookahead stream", "lookahead invert", "regression rows", "MAT dimensions",
         "MAT dimensions list", "MAT nested struct", "MAT nested cell", "MAT zip bomb", "MAT zip bomb 1 GiB"]


@pytest.mark.parametrize("name", NAMES)
def test_a_size_past_its_cap_is_refused_before_allocating(name):
    if name.startswith("MAT"):
        pytest.importorskip("scipy")
    p = subprocess.run([sys.executable, "-c", CHILD, name], capture_output=True, text=True, timeout=300,
                       env=dict(os.environ, OPENBLAS_NUM_THREADS="1"))
    assert p.returncode == 0, p.stdout + p.stderr
    assert p.stdout.startswith("refused:"), p.stdout + p.stderr

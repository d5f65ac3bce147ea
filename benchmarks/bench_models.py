"""Model step cost against its natural peer, measured in the same run.

1. The SP2 per-spindle model (2 terms) stepped one sample at a time through
   `CompensationModel.step` (what the daemon does), against
   `scipy.signal.lfilter` called per sample with its `zi` state for each term
   (plus the same input arithmetic). Target: ≥ 5x faster (aim 10x).
2. `TfBank`: 10,000 independent third-order channels stepped together;
   target < 100 µs per sample. Peer: the same bank with plain numpy
   temporaries (no `out=`), and per-channel Python stepping extrapolated.

Run: .venv/bin/python benchmarks/bench_models.py
"""

from __future__ import annotations

import time

import numpy as np
from scipy.signal import lfilter

from compd.infiles import load_model
from models.bank import TfBank
from models.tf import TransferFunction


def _best_of(fn: object, repeats: int = 7) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()  # type: ignore[operator]
        times.append(time.perf_counter() - t0)
    return min(times)


def bench_model_step(n: int = 20_000) -> tuple[float, float]:
    rng = np.random.default_rng(0)
    bearing = (22.0 + np.cumsum(rng.normal(0.0005, 0.01, n))).tolist()
    ambient = (20.0 + np.cumsum(rng.normal(0.0, 0.005, n))).tolist()
    samples = [{"bearing": b, "ambient": a} for b, a in zip(bearing, ambient, strict=True)]

    model = load_model("sp2")
    model.set_references({"bearing": 22.0, "ambient": 20.0})

    def ours() -> list[float]:
        model.reset()
        step = model.step
        return [step(s) for s in samples]

    filters = [(np.array(t.dynamics.num), np.array(t.dynamics.den)) for t in model.terms
               if isinstance(t.dynamics, TransferFunction)]
    refs = {"bearing": 22.0, "ambient": 20.0}
    channels = ["bearing", "ambient"]

    def peer() -> list[float]:
        zis = [np.zeros(max(len(a), len(b)) - 1) for b, a in filters]
        out = []
        for s in samples:
            total = 0.0
            for j, (b, a) in enumerate(filters):
                u = np.array([s[channels[j]] - refs[channels[j]]])
                y, zis[j] = lfilter(b, a, u, zi=zis[j])
                total += float(y[0])
            out.append(total)
        return out

    np.testing.assert_allclose(ours(), peer(), rtol=1e-9, atol=1e-9)
    t_ours = _best_of(ours) / n
    t_peer = _best_of(peer, repeats=3) / n
    return t_ours, t_peer


def bench_bank(channels: int = 10_000, steps: int = 2_000) -> tuple[float, float]:
    rng = np.random.default_rng(1)
    tfs = [TransferFunction(["10.01220", "-9.9895457"], ["1", "-0.877647", "0.020108",
                                                          "-0.141865"], "e1")]
    num = np.tile(np.array(tfs[0].num + (0.0,) * (4 - len(tfs[0].num))), (channels, 1))
    den = np.tile(np.array(tfs[0].den), (channels, 1))
    num *= rng.uniform(0.5, 1.5, (channels, 1))
    bank = TfBank(num, den)
    u = rng.normal(0, 1, (steps, channels))

    def ours() -> None:
        bank.reset()
        for row in u:
            bank.step(row)

    b_t, a_t = num.T.copy(), den.T.copy()

    def naive() -> None:
        z = np.zeros((3, channels))
        for row in u:
            y = b_t[0] * row + z[0]
            z[0] = b_t[1] * row + z[1] - a_t[1] * y
            z[1] = b_t[2] * row + z[2] - a_t[2] * y
            z[2] = b_t[3] * row - a_t[3] * y

    return _best_of(ours, 3) / steps, _best_of(naive, 3) / steps


def main() -> None:
    ours, peer = bench_model_step()
    print("SP2 per-spindle model (2 terms), one sample per call")
    print(f"  compd CompensationModel.step        {ours * 1e6:8.3f} µs/step")
    print(f"  scipy.signal.lfilter per sample, zi {peer * 1e6:8.3f} µs/step")
    print(f"  ratio (lfilter / compd)             {peer / ours:8.1f}x   target ≥ 5x")
    bank, naive = bench_bank()
    print("TfBank: 10,000 independent 3rd-order channels, one sample")
    print(f"  compd TfBank.step (in-place numpy)  {bank * 1e6:8.1f} µs/sample   target < 100 µs")
    print(f"  plain numpy bank with temporaries   {naive * 1e6:8.1f} µs/sample")
    print(f"  ratio (plain / compd)               {naive / bank:8.2f}x")


if __name__ == "__main__":
    main()

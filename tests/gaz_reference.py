"""The published Panda model of Gaz et al. (2019), evaluated as a reference at run time.

Their model ships as MATLAB files (GPL-3) in ../shared/realdata/panda-gaz2019/model/, which stay
out of this tree. This module holds none of their code or numbers: it reads their files when
they are present and evaluates the symbolic expressions in them with numpy (a small reader of
the MATLAB subset those generated files use: scalar assignments and column vectors of
expressions with ``.*``, ``.^``, ``./``, sin and cos). The friction model is the sigmoid of
their paper, τ_f = φ1/(1 + e^{−φ2 (q̇ + φ3)}) − φ1/(1 + e^{−φ2 φ3}), with φ read from their
friction file. Coriolis and centrifugal torques, whose file is not in the shared copy, follow
from their M(q) by the Christoffel symbols, c(q, q̇) = Ṁ q̇ − ½ ∂(q̇ᵀ M q̇)/∂q, with ∂M/∂q by
central differences.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from realdata import realdata

MODEL_DIR = realdata("panda-gaz2019")
FILES = {
    "mass": "model/matlab_dyn_model_panda_get_MassMatrix.m",
    "gravity": "model/matlab_dyn_model_panda_get_GravityVector.m",
    "friction": "model/matlab_dyn_model_panda_get_FrictionTorque.m",
}
LOG_DIR = MODEL_DIR / "rbt_log"


def available() -> bool:
    return all((MODEL_DIR / f).is_file() for f in FILES.values()) and LOG_DIR.is_dir()


def _statements(path: Path) -> list[tuple[str, str]]:
    """``name = expression`` statements of a MATLAB file (comments and ``...`` joins removed;
    statements end at ``;`` or a line end outside brackets)."""
    text = "\n".join(line.split("%", 1)[0] for line in path.read_text().splitlines())
    text = text.replace("...\n", " ")
    out = []
    for stmt in _split_top(text.replace("\n", ";"), ";"):
        m = re.fullmatch(r"([A-Za-z_]\w*)\s*=\s*(.+)", stmt, flags=re.S)
        if m:
            out.append((m.group(1), m.group(2).strip()))
    return out


def _python(expr: str) -> str:
    return expr.replace(".*", "*").replace(".^", "**").replace("./", "/").replace("^", "**")


def _split_top(s: str, sep: str) -> list[str]:
    parts, depth, cur = [], 0, []
    for ch in s:
        depth += (ch in "([" and 1) or 0
        depth -= (ch in ")]" and 1) or 0
        if ch == sep and depth == 0:
            parts.append("".join(cur))
            cur = []
        else:
            cur.append(ch)
    parts.append("".join(cur))
    return [p.strip() for p in parts if p.strip()]


class _Generated:
    """Evaluates one generated function of q (N, 7) → the list of its output vector's entries."""

    def __init__(self, path: Path, output: str) -> None:
        self.steps = []
        self.output = None
        for name, expr in _statements(path):
            if name == output or (expr.startswith("[") and name.endswith("_hat")):
                body = expr.strip()[1:-1]
                self.output = [
                    compile(_python(e), path.name, "eval") for e in _split_top(body, ";")
                ]
            elif not expr.startswith("[") and not name.startswith("q"):
                self.steps.append((name, compile(_python(expr), path.name, "eval")))
        if self.output is None:
            raise ValueError(f"{path}: no vector output found")

    def __call__(self, q: np.ndarray) -> list[np.ndarray]:
        env = {"sin": np.sin, "cos": np.cos, "exp": np.exp}
        env.update({f"q{i + 1}": q[:, i] for i in range(q.shape[1])})
        for name, code in self.steps:
            env[name] = eval(code, env)
        return [np.broadcast_to(eval(c, env), q.shape[:1]) for c in self.output]


class GazModel:
    """M(q), g(q), c(q, q̇), friction(q̇) and τ of the published model, vectorized over samples."""

    def __init__(self, root: Path = MODEL_DIR) -> None:
        self._mass = _Generated(root / FILES["mass"], "Bstack_hat")
        self._gravity = _Generated(root / FILES["gravity"], "g_li_hat")
        fp = dict(_statements(root / FILES["friction"]))["fp"]
        rows = _split_top(fp.strip()[1:-1], ";")
        self.friction_phi = np.array([[float(x) for x in r.split(",")] for r in rows])
        # Bstack_hat holds the upper triangle of M column by column (their MassMatrix layout).
        self._packed = [(i, j) for j in range(7) for i in range(j + 1)]

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        entries = self._mass(q)
        M = np.empty((len(q), 7, 7))
        for value, (i, j) in zip(entries, self._packed, strict=True):
            M[:, i, j] = M[:, j, i] = value
        return M

    def gravity_vector(self, q: np.ndarray) -> np.ndarray:
        return np.stack(self._gravity(q), axis=-1)

    def friction_torque(self, dq: np.ndarray) -> np.ndarray:
        A, _, phi, alpha = self.friction_phi
        return A / (1 + np.exp(-alpha * (dq + phi))) - A / (1 + np.exp(-alpha * phi))

    def coriolis_vector(self, q: np.ndarray, dq: np.ndarray, step: float = 1e-6) -> np.ndarray:
        """c = Ṁ q̇ − ½ ∂(q̇ᵀ M q̇)/∂q, i.e. Σ_k ∂M/∂q_k q̇_k q̇ − ½ [q̇ᵀ ∂M/∂q_i q̇]_i."""
        c = np.zeros_like(q)
        for k in range(7):
            e = np.zeros(7)
            e[k] = step
            dM = (self.mass_matrix(q + e) - self.mass_matrix(q - e)) / (2 * step)
            dMdq = np.einsum("nij,nj->ni", dM, dq)
            c += dMdq * dq[:, k : k + 1]
            c[:, k] -= 0.5 * np.einsum("ni,ni->n", dq, dMdq)
        return c

    def torque(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        M = self.mass_matrix(q)
        return (
            np.einsum("nij,nj->ni", M, ddq)
            + self.coriolis_vector(q, dq)
            + self.gravity_vector(q)
            + self.friction_torque(dq)
        )

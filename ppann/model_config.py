"""The PPANN's architecture and physical prior (`PPANNConfig`), in a module of its own so that
what a checkpoint's `config` holds is read in one place (ppann/model.py builds from it)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

from common.checks import check_choice, check_finite
from common.errors import CrankError

MACHINE_TERMS = ("augmented", "prior")
"""What the machine-level log-factors scale (`PPANNConfig.machine_terms`)."""
ANGLE_UPDATES = ("euler", "trapezoid")
"""How a step moves the angle (`PPANNConfig.angle_update`)."""
WHITE_INERTIA = ("quotient", "linear")
"""How a Monte-Carlo draw of z_J's white noise enters the acceleration
(`PPANNConfig.white_inertia`)."""


class ModelConfigError(CrankError, ValueError):
    """A PPANN configuration value is out of range."""


@dataclass(frozen=True)
class PPANNConfig:
    """Architecture and physical prior of a PPANN (paper section 3.3.1)."""

    j_m: float = 3e-3
    """Prior motor inertia J_m, kg·m²."""
    b_m: float = 0.1
    """Prior viscous damping B_m, N·m·s/rad."""
    k_m: float = 1.0
    """Prior stiffness K_m, N·m/rad."""
    mean_hidden: int = 100
    sigma_hidden: int = 10
    sigma_floor: float = 1e-4
    """Smallest standard deviation a sigma network can output."""
    omega_scale: float = 50.0
    """omega is divided by this before it enters a network, rad/s."""
    dt: float = 1 / 500
    trainable_physics: bool = False
    """Train J_m, B_m, K_m along with the mean networks."""
    use_networks: bool = True
    """False gives the physics-only baseline: z = 0, J_m, B_m, K_m fitted."""
    sigma_speed: bool = False
    """The sigma networks of z_J and z_K see omega too (beyond the paper, whose z_J and z_K
    networks see the angle alone): the residual's spread at one angle can depend on the speed.
    A checkpoint without this key is of the paper's architecture (False)."""
    sigma_wrap: bool = False
    """The sigma network of z_K also sees theta_mod / 2 pi (beyond the paper): its white noise
    enters eq. 14 as K z_K theta_mod, which jumps from ~2 pi K to 0 at the wrap (top dead
    centre), and a network of (sin, cos) alone must give it one σ on both sides; with the
    wrapped angle it can make the noise small just before the wrap. Not with `sigma_speed`.
    A checkpoint without this key is of the paper's architecture (False)."""
    mean_wrap: bool = False
    """The mean network of z_K also sees theta_mod / 2 pi (beyond the paper): eq. 14's stiffness
    term K_m (1 + z_K) theta_mod jumps with theta_mod from ~2 pi K_m to 0 at the wrap (top dead
    centre), and a network of (sin, cos) alone is continuous there, so the term cannot carry a
    load torque that is continuous across it (the slider's weight through the kinematics): on
    the twin, z_K's mean sits near -1 on both sides and the static torque is off by up to
    0.15 N·m beside top dead centre. With the wrapped angle 1 + z_K can jump where theta_mod
    does. A checkpoint without this key is of the paper's architecture (False)."""
    sigma_lever: bool = False
    """A white force on the slider beside the sigma networks (beyond the paper; ppann/lever.py):
    eq. 14's torque balance gets x'(theta) F, F ~ N(0, lever_sigma^2), which vanishes at the
    dead centres where the networks' channels cannot. A checkpoint without this key has none."""
    machine_terms: str = "augmented"
    """What a machine's log-factors eta (ppann/machine.py) scale. "augmented": eq. 14's whole
    term, J_m (1 + z_J) e^eta_J, and so for B and K. "prior" (beyond the paper): the prior's
    physical term alone, J_m (1 + z_J + e^eta_J - 1): the motor's inertia, damping and stiffness
    vary from machine to machine, the networks' corrections (the slider's inertia, the velocity
    products the B network absorbs) do not. A checkpoint without this key is "augmented"."""

    coulomb: bool = False
    """Coulomb friction in the prior (beyond the paper; ppann/friction.py): eq. 13's torque
    balance loses C tanh(omega / coulomb_speed), the motor's, and F x'(theta) tanh(x'(theta)
    omega / (coulomb_speed l1)), the slider's through the kinematics; C = coulomb_m e^c0 and
    F = coulomb_load e^c1 with c fitted in phase 1 beside the mean networks. Eq. 14's B term,
    B_m (1 + z_B) omega, cannot form either: it vanishes with omega. A machine's damping factor
    e^eta_B (ppann/machine.py) scales both with the damping term: its whole friction. A
    checkpoint without this key has none."""
    coulomb_m: float = 0.05
    """Prior Coulomb torque of the motor C_m, N·m (a motor datasheet's order; fitted from it)."""
    coulomb_load: float = 1.0
    """Prior Coulomb force of the slider F_m, N (fitted from it)."""
    coulomb_speed: float = 0.1
    """Motor speed over which the Coulomb torques' tanh turns, rad/s: smooth for the OCP, and
    with forward Euler at dt stable for C / (coulomb_speed J) dt < 1."""

    white_inertia: str = "quotient"
    """How the Monte-Carlo's draw of z_J's white noise enters the acceleration (the mean model
    and training are the same either way). "quotient", the paper's eq. 14 with z drawn (eq. 11):
    alpha = (tau - ...) / (J_m (1 + z_J)), whose average over the draws is not the mean model's
    alpha: E[1 / (1 + mu + sigma eps)] = (1 + rho^2 + ...) / (1 + mu), rho = sigma / (1 + mu),
    2-4 % at the rho of up to 0.16-0.20 a default model has over top dead centre (3-7 % at a plan
    round's 0.15-0.24), where phase 1 fitted the mean networks to the data's average
    acceleration; the draws so move the Monte-Carlo's mean and widen its spread. "linear"
    (beyond the paper; `TrainConfig.white_inertia`'s default since session 55): the draw to
    first order about the mean, alpha(mu) (1 - sigma eps / (1 + mu)), zero-mean, the spread
    eq. 9 fitted (its residual is linear in z at the observed acceleration). A checkpoint
    without this key is "quotient"."""

    angle_update: str = "euler"
    """How a step moves the angle. "euler", the paper's forward Euler (eq. 4): theta_{k+1} =
    theta_k + dt omega_k, which from rest leaves the angle dt (omega_k - omega_1) / 2 behind the
    motion (bench/mean_offset.md: 23 mrad at sample 10). "trapezoid" (beyond the paper): theta_{k+1}
    = theta_k + dt (omega_k + omega_{k+1}) / 2 = theta_k + dt omega_k + dt^2 alpha_k / 2, with
    omega_{k+1} = omega_k + dt alpha_k as in eq. 4. A checkpoint without this key is "euler"."""

    def __post_init__(self) -> None:
        positive = ("j_m", "b_m", "omega_scale", "dt", "sigma_floor")
        positive += ("coulomb_m", "coulomb_load", "coulomb_speed")
        for name in positive:
            check_finite(name, getattr(self, name), positive=True, error=ModelConfigError)
        check_finite("k_m", self.k_m, error=ModelConfigError)
        for name in ("mean_hidden", "sigma_hidden"):
            if getattr(self, name) < 1:
                raise ModelConfigError(f"{name} must be >= 1, got {getattr(self, name)}")
        check_choice("machine_terms", self.machine_terms, MACHINE_TERMS, error=ModelConfigError)
        check_choice("white_inertia", self.white_inertia, WHITE_INERTIA, error=ModelConfigError)
        check_choice("angle_update", self.angle_update, ANGLE_UPDATES, error=ModelConfigError)
        if self.sigma_wrap and self.sigma_speed:
            raise ModelConfigError("sigma_wrap and sigma_speed cannot be combined")

    @property
    def half_step(self) -> float:
        """dt^2 / 2 with the trapezoid angle update, else 0: theta_{k+1} = theta_k + dt omega_k
        + half_step alpha_k (added only when nonzero, so Euler's numbers stay to the bit)."""
        return 0.5 * self.dt * self.dt if self.angle_update == "trapezoid" else 0.0

    def as_dict(self) -> dict:
        return asdict(self)

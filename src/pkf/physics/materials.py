"""Material effects in thin silicon-equivalent layers: scattering, energy loss, bremsstrahlung.

docs/physics.md#material-effects. Units: momenta, energies and masses in MeV (c = 1), lengths in mm, angles
in rad, material thickness either in mm of silicon or as t = path length in radiation
lengths X0. Every function here is a scalar ``@njit(cache=True)`` kernel callable from
other compiled code (the simulation's transport loop and the reference Kalman fit);
the random samplers use numba's own generator (seed it with `seed_rng`, not with
``np.random.seed`` from Python: numba keeps a separate state per thread).

A layer of thickness x/X0 crossed with slopes (tx, ty) is t = (x/X0)·N radiation
lengths, N = √(1 + tx² + ty²) (`path_length_x0`), which is `silicon_thickness_mm`
= t·X0(Si) millimetres of silicon for the energy loss.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from pkf.physics.constants import MASS_ELECTRON

# --- constants (PDG RPP 2024, "Passage of particles through matter", Table 34.1) -----
ELECTRON_MASS = MASS_ELECTRON  # MeV
BETHE_K = 0.307075  # 4π N_A r_e² m_e c², MeV cm²/mol
HIGHLAND_SCALE = 13.6  # MeV
HIGHLAND_LOG = 0.038
EULER_GAMMA = 0.5772156649015329
LN2 = math.log(2.0)
LN10 = math.log(10.0)

# --- silicon (PDG "Atomic and nuclear properties of materials", Si) ------------------
SI_Z_OVER_A = 0.49848  # mol/g
SI_MEAN_EXCITATION = 173.0e-6  # I, MeV
SI_DENSITY = 2.329  # g/cm³
SI_X0_MM = 93.7  # radiation length, mm
# Sternheimer density-effect parameters for silicon (Sternheimer, Berger & Seltzer,
# At. Data Nucl. Data Tables 30 (1984) 261, as tabulated by the PDG): C̄ = 2 ln(I/ħω_p) + 1
# with ħω_p = 31.05 eV; δ = 2 ln10·x − C̄ + a (x1 − x)^k for x0 ≤ x < x1, x = log10(βγ).
SI_STERNHEIMER_CBAR = 4.4355
SI_STERNHEIMER_X0 = 0.2014
SI_STERNHEIMER_X1 = 2.8715
SI_STERNHEIMER_A = 0.14921
SI_STERNHEIMER_K = 3.2546
SI_STERNHEIMER_DELTA0 = 0.14  # conductor: δ(x < x0) = δ0·10^{2(x − x0)}

# Mean of the standard Moyal variable λ = −2 ln|Z|, Z ~ N(0, 1): γ_E + ln 2.
MOYAL_MEAN = EULER_GAMMA + LN2


@nb.njit(cache=True)
def seed_rng(seed):
    """Seed numba's random generator (the one the samplers below draw from)."""
    np.random.seed(seed)


@nb.njit(cache=True)
def path_length_x0(x_over_x0, tx, ty):
    """Path length t [X0] through a plane of thickness x/X0 crossed with slopes (tx, ty)."""
    return x_over_x0 * math.sqrt(1.0 + tx * tx + ty * ty)


@nb.njit(cache=True)
def silicon_thickness_mm(x_over_x0, tx, ty):
    """Equivalent silicon path [mm] through a plane of x/X0 crossed with slopes (tx, ty)."""
    return path_length_x0(x_over_x0, tx, ty) * SI_X0_MM


# ----------------------------------------------------------------------------------
# Multiple scattering
# ----------------------------------------------------------------------------------


@nb.njit(cache=True)
def highland_theta0(p, mass, charge, t):
    """Width θ0 [rad] of the projected scattering angle (Highland, PDG eq. 34.16).

    θ0 = 13.6 MeV/(β p)·|q|·√t·[1 + 0.038·ln(t q²/β²)], p [MeV] > 0, mass [MeV],
    charge in units of e, t = path length in radiation lengths. Returns 0 for t ≤ 0.
    """
    if t <= 0.0 or p <= 0.0:
        return 0.0
    beta = p / math.sqrt(p * p + mass * mass)
    q2 = charge * charge
    return (
        HIGHLAND_SCALE / (beta * p) * abs(charge) * math.sqrt(t)
        * (1.0 + HIGHLAND_LOG * math.log(t * q2 / (beta * beta)))
    )


@nb.njit(cache=True)
def scattering_noise(tx, ty, theta0_sq):
    """Thin-scatterer covariance of the slopes for a projected-angle variance θ0² (docs/physics.md#material-effects).

    Returns (Q_txtx, Q_txty, Q_tyty) = θ0²N²·((1+tx²), tx·ty, (1+ty²)), N² = 1+tx²+ty².
    """
    n2 = 1.0 + tx * tx + ty * ty
    s = theta0_sq * n2
    return s * (1.0 + tx * tx), s * tx * ty, s * (1.0 + ty * ty)


@nb.njit(cache=True)
def deflect(tx, ty, theta1, theta2):
    """Slopes after deflecting the direction (tx, ty, 1) by small angles θ1, θ2 [rad].

    θ1 and θ2 are the projected angles in two orthonormal directions perpendicular to
    the track: u = (1, 0, −tx)/√(1+tx²) (in the x–z plane) and v = d × u. The direction
    is rotated exactly by the polar angle √(θ1²+θ2²) about the axis ⟂ to d. If the new
    direction points backwards in z (d_z ≤ 0) the slopes are returned as ±inf.
    """
    inv_n = 1.0 / math.sqrt(1.0 + tx * tx + ty * ty)
    dx = tx * inv_n
    dy = ty * inv_n
    dz = inv_n
    inv_u = 1.0 / math.sqrt(dx * dx + dz * dz)
    ux = dz * inv_u
    uz = -dx * inv_u
    # v = d × u with u = (ux, 0, uz)
    vx = dy * uz
    vy = dz * ux - dx * uz
    vz = -dy * ux
    theta = math.sqrt(theta1 * theta1 + theta2 * theta2)
    if theta == 0.0:
        return tx, ty
    c = math.cos(theta)
    s = math.sin(theta) / theta
    nx = c * dx + s * (theta1 * ux + theta2 * vx)
    ny = c * dy + s * (theta2 * vy)
    nz = c * dz + s * (theta1 * uz + theta2 * vz)
    if nz <= 0.0:
        return math.copysign(math.inf, nx), math.copysign(math.inf, ny)
    return nx / nz, ny / nz


@nb.njit(cache=True)
def apply_scattering(tx, ty, theta0):
    """New slopes after a random multiple-scattering kick of projected width θ0 [rad].

    Two independent Gaussian angles N(0, θ0²) in the plane perpendicular to the
    direction (see `deflect`); to first order the slope covariance is `scattering_noise`.
    """
    if theta0 <= 0.0:
        return tx, ty
    return deflect(tx, ty, np.random.normal(0.0, theta0), np.random.normal(0.0, theta0))


# ----------------------------------------------------------------------------------
# Ionisation energy loss
# ----------------------------------------------------------------------------------


@nb.njit(cache=True)
def silicon_density_effect(beta_gamma):
    """Density-effect correction δ(βγ) for silicon (Sternheimer parametrisation, PDG eq. 34.7)."""
    x = math.log10(beta_gamma)
    if x >= SI_STERNHEIMER_X1:
        return 2.0 * LN10 * x - SI_STERNHEIMER_CBAR
    if x >= SI_STERNHEIMER_X0:
        return (
            2.0 * LN10 * x - SI_STERNHEIMER_CBAR
            + SI_STERNHEIMER_A * (SI_STERNHEIMER_X1 - x) ** SI_STERNHEIMER_K
        )
    return SI_STERNHEIMER_DELTA0 * 10.0 ** (2.0 * (x - SI_STERNHEIMER_X0))


@nb.njit(cache=True)
def bethe_stopping_power(p, mass):
    """Mean mass stopping power ⟨−dE/dx⟩ [MeV cm²/g] of silicon for a unit-charge particle.

    Bethe formula (PDG eq. 34.5) with the maximum energy transfer W_max (eq. 34.4) and
    the density-effect correction (`silicon_density_effect`); no shell or Barkas/Bloch
    corrections (they matter only below βγ ≈ 0.1). p, mass in MeV.
    """
    if p <= 0.0:
        return 0.0
    bg = p / mass
    bg2 = bg * bg
    gamma = math.sqrt(1.0 + bg2)
    beta2 = bg2 / (1.0 + bg2)
    ratio = ELECTRON_MASS / mass
    wmax = 2.0 * ELECTRON_MASS * bg2 / (1.0 + 2.0 * gamma * ratio + ratio * ratio)
    log_term = 0.5 * math.log(
        2.0 * ELECTRON_MASS * bg2 * wmax / (SI_MEAN_EXCITATION * SI_MEAN_EXCITATION)
    )
    bracket = log_term - beta2 - 0.5 * silicon_density_effect(bg)
    if bracket < 0.0:  # far below the validity of the formula (βγ ≲ 0.05)
        return 0.0
    return BETHE_K * SI_Z_OVER_A / beta2 * bracket


@nb.njit(cache=True)
def bethe_mean_loss(p, mass, thickness_mm):
    """Mean energy [MeV] lost by a unit-charge particle in `thickness_mm` of silicon.

    Bethe with density effect (`bethe_stopping_power`) times the areal density
    ρ·x; the stopping power is taken at the entrance momentum (thin layers). The loss
    is not capped at the kinetic energy (use `apply_energy_loss_to_qop` for that).
    """
    if thickness_mm <= 0.0:
        return 0.0
    return bethe_stopping_power(p, mass) * SI_DENSITY * 0.1 * thickness_mm


@nb.njit(cache=True)
def landau_xi(p, mass, thickness_mm):
    """Landau/Moyal scale ξ = (K/2)(Z/A)·ρx/β² [MeV] in silicon (PDG eq. 34.11)."""
    if thickness_mm <= 0.0 or p <= 0.0:
        return 0.0
    beta2 = p * p / (p * p + mass * mass)
    return 0.5 * BETHE_K * SI_Z_OVER_A * SI_DENSITY * 0.1 * thickness_mm / beta2


@nb.njit(cache=True)
def sample_moyal():
    """A standard Moyal variate λ = −2 ln|Z|, Z ~ N(0, 1); mean γ_E + ln 2, variance π²/2."""
    z = abs(np.random.normal(0.0, 1.0))
    while z == 0.0:  # probability zero, but keep the logarithm finite
        z = abs(np.random.normal(0.0, 1.0))
    return -2.0 * math.log(z)


@nb.njit(cache=True)
def sample_energy_loss(p, mass, thickness_mm):
    """A random ionisation energy loss [MeV] in `thickness_mm` of silicon.

    Moyal-distributed with scale ξ (`landau_xi`), shifted so that its mean equals the
    Bethe mean (`bethe_mean_loss`): Δ = Δ̄ + ξ·(λ − (γ_E + ln 2)). Clipped to
    [0, kinetic energy]; the clipping only acts in the far tails for thin layers.
    """
    if thickness_mm <= 0.0 or p <= 0.0:
        return 0.0
    mean = bethe_mean_loss(p, mass, thickness_mm)
    xi = landau_xi(p, mass, thickness_mm)
    loss = mean + xi * (sample_moyal() - MOYAL_MEAN)
    kinetic = math.sqrt(p * p + mass * mass) - mass
    if loss < 0.0:
        return 0.0
    if loss > kinetic:
        return kinetic
    return loss


@nb.njit(cache=True)
def apply_energy_loss_to_qop(qop, mass, delta_e):
    """q/p [1/MeV] after the particle's energy changes by −delta_e [MeV].

    delta_e > 0 is a loss (forward transport), delta_e < 0 a gain (e.g. when a fit
    runs against the flight direction). If the particle stops (E − ΔE ≤ m) the result
    is ±inf (zero momentum, sign of the charge kept): test ``abs(qop) > 1/p_min``.
    qop = 0 (infinite momentum, or neutral) is returned unchanged.
    """
    if qop == 0.0 or delta_e == 0.0:
        return qop
    p = 1.0 / abs(qop)
    energy = math.sqrt(p * p + mass * mass) - delta_e
    if energy <= mass:
        return math.copysign(math.inf, qop)
    return math.copysign(1.0, qop) / math.sqrt((energy - mass) * (energy + mass))


@nb.njit(cache=True)
def energy_loss_qop_derivative(qop, mass, delta_e):
    """∂qop_out/∂qop_in of `apply_energy_loss_to_qop` at fixed delta_e (for Jacobians).

    With E' = E − ΔE and p' = √(E'² − m²): ∂qop'/∂qop = (p/p')³·E'/E.
    Returns 1 for qop = 0 or delta_e = 0, and inf if the particle stops.
    """
    if qop == 0.0 or delta_e == 0.0:
        return 1.0
    p = 1.0 / abs(qop)
    energy = math.sqrt(p * p + mass * mass)
    energy_out = energy - delta_e
    if energy_out <= mass:
        return math.inf
    p_out = math.sqrt((energy_out - mass) * (energy_out + mass))
    r = p / p_out
    return r * r * r * energy_out / energy


# ----------------------------------------------------------------------------------
# Bremsstrahlung (electrons)
# ----------------------------------------------------------------------------------


@nb.njit(cache=True)
def sample_bremsstrahlung_fraction(t):
    """Fraction z = E_f/E_i of an electron's energy kept after t radiation lengths.

    Bethe–Heitler: −ln z ~ Gamma(shape t/ln 2, scale 1), so E[−ln z] = t/ln 2 and
    E[z] = 2^{−t/ln 2} = e^{−t}. Returns 1 for t ≤ 0.
    """
    if t <= 0.0:
        return 1.0
    return math.exp(-np.random.gamma(t / LN2, 1.0))


@nb.njit(cache=True)
def bremsstrahlung_fraction_moments(t):
    """Mean and variance of the Bethe–Heitler fraction z = E_f/E_i after t [X0]:
    E[z] = e^{−t}, E[z²] = 3^{−t/ln 2}, so Var z = e^{−t·ln 3/ln 2} − e^{−2t}
    (the moments LHCb's electron fit adds, StateElectronEnergyCorrectionTool). (1, 0) for t ≤ 0."""
    if t <= 0.0:
        return 1.0, 0.0
    return math.exp(-t), math.exp(-t * math.log(3.0) / LN2) - math.exp(-2.0 * t)


@nb.njit(cache=True)
def apply_bremsstrahlung_to_qop(qop, mass, z):
    """q/p [1/MeV] after the total energy is scaled by z = E_f/E_i (±inf if E_f ≤ m)."""
    if qop == 0.0:
        return qop
    p = 1.0 / abs(qop)
    energy = z * math.sqrt(p * p + mass * mass)
    if energy <= mass:
        return math.copysign(math.inf, qop)
    return math.copysign(1.0, qop) / math.sqrt((energy - mass) * (energy + mass))


# ----------------------------------------------------------------------------------
# Vectorised wrappers (Python-side convenience; the kernels above are the interface)
# ----------------------------------------------------------------------------------


@nb.njit(cache=True)
def bethe_mean_loss_array(p, mass, thickness_mm):
    """`bethe_mean_loss` over an array of momenta p [MeV] (same mass and thickness)."""
    out = np.empty(p.size)
    for i in range(p.size):
        out[i] = bethe_mean_loss(p[i], mass, thickness_mm)
    return out


@nb.njit(cache=True)
def sample_energy_loss_array(n, p, mass, thickness_mm):
    """n samples of `sample_energy_loss` [MeV] at one momentum."""
    out = np.empty(n)
    for i in range(n):
        out[i] = sample_energy_loss(p, mass, thickness_mm)
    return out


@nb.njit(cache=True)
def apply_scattering_array(n, tx, ty, theta0):
    """n independent `apply_scattering` draws from the same (tx, ty); returns (n, 2) slopes."""
    out = np.empty((n, 2))
    for i in range(n):
        a, b = apply_scattering(tx, ty, theta0)
        out[i, 0] = a
        out[i, 1] = b
    return out


@nb.njit(cache=True)
def sample_bremsstrahlung_fraction_array(n, t):
    """n samples of `sample_bremsstrahlung_fraction`."""
    out = np.empty(n)
    for i in range(n):
        out[i] = sample_bremsstrahlung_fraction(t)
    return out

"""Compiled physics shared by the simulation and the reference Kalman fit.

Runge–Kutta transport in z with its Jacobian (`transport`) and thin-layer material
effects — multiple scattering, ionisation energy loss, bremsstrahlung (`materials`).
Units: mm, MeV (c = 1), tesla, rad (docs/physics.md).
"""

from pkf.physics.materials import (
    ELECTRON_MASS,
    SI_X0_MM,
    apply_bremsstrahlung_to_qop,
    apply_energy_loss_to_qop,
    apply_scattering,
    bethe_mean_loss,
    bethe_stopping_power,
    deflect,
    energy_loss_qop_derivative,
    highland_theta0,
    landau_xi,
    path_length_x0,
    sample_bremsstrahlung_fraction,
    sample_energy_loss,
    scattering_noise,
    seed_rng,
    silicon_density_effect,
    silicon_thickness_mm,
)
from pkf.physics.transport import (
    C_LIGHT,
    rk4_propagate,
    rk4_propagate_jacobian,
    rk4_propagate_many,
    rk4_propagate_scalar,
    slope_derivatives,
)

__all__ = [
    "ELECTRON_MASS", "SI_X0_MM", "C_LIGHT",
    "apply_bremsstrahlung_to_qop", "apply_energy_loss_to_qop", "apply_scattering",
    "bethe_mean_loss", "bethe_stopping_power", "deflect", "energy_loss_qop_derivative",
    "highland_theta0", "landau_xi", "path_length_x0", "sample_bremsstrahlung_fraction",
    "sample_energy_loss", "scattering_noise", "seed_rng", "silicon_density_effect",
    "silicon_thickness_mm",
    "rk4_propagate", "rk4_propagate_jacobian", "rk4_propagate_many", "rk4_propagate_scalar",
    "slope_derivatives",
]

"""The options of a fit: the outlier rejection every fitter shares, and one object per fitter.

`FitOptions` is what every fit function takes (``fit(extrapolator, batch, options, …)``):
the outlier cut and the largest number of removals (`pkf.fit.driver`), and the options of
each fitter family — `KalmanOptions` (parametrized and reference Kalman fitters),
`GX2FOptions` (global χ² fitter) and `GSFOptions` (Gaussian-sum filter). A fitter reads
its own object and ignores the others. `pkf reconstruct` builds them from its options
(docs/cli.md); `ReconstructionConfig` holds the same objects.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.special import chdtrc, chdtri

#: Kalman combination methods (docs/physics.md#the-kalman-core): the weighted mean of the
#: forward prediction and the backward filter, the Rauch–Tung–Striebel smoother (the same
#: states, a test checks it), or none (forward filtered states: for timing studies).
SMOOTHERS = ("weighted-mean", "rts", "forward-only")
#: The Kalman fitters' particle hypotheses (docs/physics.md#particle-hypotheses; `pkf.fit.hypothesis`).
HYPOTHESES = ("pion", "electron")
#: What the GSF writes as a node's state (docs/physics.md; `pkf.fit.gsf`).
GSF_OUTPUTS = ("core", "mode", "max-weight", "mean")


@dataclass(frozen=True)
class KalmanOptions:
    """The Kalman fitters' options: `iterations`, the number of passes (the 2nd and later
    linearise around the previous optimal states; None: one pass, `pkf reconstruct` then
    uses each fitter's own default, `pkf.fit.fitters.Fitter.iterations`), `smoother`,
    one of `SMOOTHERS`, and `hypothesis`, the particle assumed by the material effects, one
    of `HYPOTHESES` (the electron adds the Bethe–Heitler loss and its variance to q/p,
    `pkf.fit.hypothesis`; the extrapolator carries it: `pkf.fit.fitters.Fitter.extrapolator`)."""

    iterations: int | None = None
    smoother: str = "weighted-mean"
    hypothesis: str = "pion"

    def __post_init__(self):
        if self.iterations is not None and self.iterations < 1:
            raise ValueError(f"iterations must be >= 1, not {self.iterations}")
        if self.smoother not in SMOOTHERS:
            raise ValueError(f"smoother must be one of {', '.join(SMOOTHERS)}, not {self.smoother!r}")
        if self.hypothesis not in HYPOTHESES:
            raise ValueError(f"hypothesis must be one of {', '.join(HYPOTHESES)}, not {self.hypothesis!r}")


@dataclass(frozen=True)
class GX2FOptions:
    """The global χ² fitter's Gauss–Newton options: at most `max_updates` updates of the
    track parameters, stopping early once χ² changes by less than `relative_chi2_change`
    of itself (docs/physics.md#the-global-χ²-fitter-gx2f)."""

    max_updates: int = 5
    relative_chi2_change: float = 1e-7

    def __post_init__(self):
        if self.max_updates < 1:
            raise ValueError(f"max_updates must be >= 1, not {self.max_updates}")
        if not self.relative_chi2_change > 0:
            raise ValueError(f"relative_chi2_change must be > 0, not {self.relative_chi2_change}")


#: The largest `GSFOptions.sibling_merge` and `product_merge` (factors of `max_components`):
#: far more components than a convolution or a smoothing makes, and a count that stays finite.
MAX_MERGE_FACTOR = 1000.0


@dataclass(frozen=True)
class GSFOptions:
    """The Gaussian-sum filter's mixture options (ACTS's defaults): at most
    `max_components` components after each reduction, components below `weight_cut` of
    the total weight dropped, and the state written per node, `output`, one of
    `GSF_OUTPUTS` (`pkf.fit.gsf`). After each Bethe–Heitler convolution, the closest pairs of
    siblings (children of one component) are merged first until at most
    `sibling_merge`·`max_components` components remain, then the closest pairs of all
    (0: all of them at once, the previous reduction; `pkf.fit.gsf`, "Reduction after a
    convolution"); in the smoothing, the products that share a component of the more precise
    filter likewise, down to `product_merge`·`max_components` (0: off). The mixtures'
    product is the smoothed state at the first and last node (the written states), and at
    every node with `mixture_smoothing_everywhere`; elsewhere the node's state (for the
    outlier search) is the product of the more precise filter's mixture with the other's
    moments (`pkf.fit.gsf`, "Smoothing at the written nodes")."""

    max_components: int = 12
    weight_cut: float = 1e-4
    output: str = "core"
    sibling_merge: float = 3.5
    product_merge: float = 2.0
    mixture_smoothing_everywhere: bool = False

    def __post_init__(self):
        if self.max_components < 1:
            raise ValueError(f"max_components must be >= 1, not {self.max_components}")
        if not 0.0 <= self.weight_cut < 1.0:
            raise ValueError(f"weight_cut must be in [0, 1), not {self.weight_cut}")
        if self.output not in GSF_OUTPUTS:
            raise ValueError(f"output must be one of {', '.join(GSF_OUTPUTS)}, not {self.output!r}")
        for name in ("sibling_merge", "product_merge"):  # factors of max_components: finite counts
            if not 0.0 <= getattr(self, name) <= MAX_MERGE_FACTOR:
                raise ValueError(f"{name} must be in [0, {MAX_MERGE_FACTOR:g}], not {getattr(self, name)}")


@dataclass(frozen=True)
class FitOptions:
    """Options of a fit (docs/physics.md#the-kalman-core): the outlier χ² cut for 1-D nodes and the
    largest number of outliers removed per track (shared by every fitter), and each
    fitter family's own options."""

    outlier_chi2: float = 9.0
    max_outliers: int = 2
    kalman: KalmanOptions = field(default_factory=KalmanOptions)
    gx2f: GX2FOptions = field(default_factory=GX2FOptions)
    gsf: GSFOptions = field(default_factory=GSFOptions)

    def outlier_cuts(self) -> np.ndarray:
        """Cuts on a node's standardised χ² for 1-D and 2-D nodes: `outlier_chi2` for 1-D,
        and for 2-D the value with the same tail probability (9 → 11.83)."""
        p_value = chdtrc(1, self.outlier_chi2)  # χ²(1) survival function (scipy.stats.chi2.sf's own)
        return np.array([self.outlier_chi2, chdtri(2, p_value)])

    @classmethod
    def from_flat(cls, **options) -> FitOptions:
        """The options from flat keywords, each routed to the object whose field it names
        (``FitOptions.from_flat(iterations=2, max_components=6)``); TypeError for an unknown one."""
        groups = {"kalman": KalmanOptions, "gx2f": GX2FOptions, "gsf": GSFOptions}
        own = {k: options.pop(k) for k in ("outlier_chi2", "max_outliers") if k in options}
        parts = {}
        for group, kind in groups.items():
            names = set(kind.__dataclass_fields__)
            parts[group] = kind(**{k: options.pop(k) for k in list(options) if k in names})
        if options:
            raise TypeError(f"unknown fit options: {', '.join(sorted(options))}")
        return cls(**own, **parts)


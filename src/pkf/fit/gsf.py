"""The Gaussian-sum filter (GSF) for electrons (docs/physics.md#the-gaussian-sum-filter-gsf-and-the-bethe-heitler-mixture, seeds/002).

The track state is a Gaussian mixture Σ_c w_c·N(μ_c, P_c) over (x, y, tx, ty, q/p).
Transport and material are those of the reference extrapolator (`pkf.fit.reference`)
applied to every component: RK4 with its Jacobian through the field map from plane to
plane, Highland slope noise and the Bethe mean ionisation loss at each material plane
(for the mass hypothesis, the electron's by default). For electrons, each component is
then convolved at every plane with pkf's Gaussian-mixture approximation of the
Bethe–Heitler distribution of z = E_f/E_i (`pkf.params.bethe_heitler`, K components
as functions of the path length t = x/X0·N; the ACTS shortcuts below t = 0.002):
component c becomes K components with weights w_c·π_b and, downstream (forward
filter, q/p′ = q/p / z), mean q/p/μ_b, Jacobian 1/μ_b on the q/p row and column and
added variance (q/p′)²·σ_b²/μ_b² (the linearisation of q/p / z); upstream (backward
filter, q/p′ = q/p·z, exact) mean q/p·μ_b, Jacobian μ_b, added variance (q/p)²·σ_b².
(E = p for electrons above 100 MeV to 1e−5.) Ionisation, then bremsstrahlung, in both
directions (the physical order upstream is the reverse; the difference in q/p is
ΔE_ion·(1 − z)/p, below 2e−4 relative even for a hard radiation at 1 GeV). A component
whose particle stops in a plane (E − ΔE ≤ m, a few-MeV hypothesis) is dropped; a track
all of whose components stop gets the status "extrapolation failed", as in the Kalman fit.

After every plane the mixture is reduced: components with weight < `weight_cut`
(1e−4) are dropped, then the closest pair in the symmetric Kullback–Leibler distance of
the q/p marginals (as ACTS: d = (v_i − v_j)(1/v_j − 1/v_i) + (μ_i − μ_j)²(1/v_i + 1/v_j))
is merged by moment matching until at most `max_components` (12) remain (nearest-
neighbour bookkeeping with vectorised rows of distances on a compact mixture, `_reduce`:
O(n²) for the first neighbours, O(n) per merge, in the n ≈ 64 of 12·K components the
weight cut leaves on lhcb-like electrons).

Reduction after a convolution (issue 18.2, third round): the children of one component (its
K Bethe–Heitler components, "siblings") share everything but the q/p row and column, and the
closest pair among a family's K is found from K(K − 1)/2 ≤ 28 distances. So the closest pair
of *siblings* is merged first (same distance, same moment matching; `_merge_siblings`, each
family keeping its own closest pair) until at most `GSFOptions.sibling_merge` ×
`max_components` components remain (3.5 × 12 = 42), then the closest pairs of all
(`_reduce`) down to 12; ACTS merges the closest pair of all from the start (a cached matrix
of symmetric KL distances, the same q/p distance). Measured (`benchmarks/electron_fits.py`
sample, lhcb-like electrons 2–50 GeV, the GSF alone; seed 7, 1,500 tracks, and seed 11, 600
events, 3,000 tracks; every difference to the all-at-once reduction with its
paired-bootstrap error over the tracks): factor 3.5 leaves the q/p pull RMS, share within
±1.2, pull core and δp/p core at the first hit, beamline, last VELO, last UT and last hit
within 1.5 σ of the differences (seed 11: first-hit pull core 0.661 → 0.661 ± 0.006, δp/p
core 13.20 → 13.49 ± 0.19 %, last-hit δp/p core 2.802 → 2.795 ± 0.021 %; seed 7: 0.671 →
0.675 ± 0.011, 15.18 → 15.31 ± 0.21 %, 2.853 → 2.909 ± 0.056 %; the last-VELO-hit pull RMS
of seed 7, 1.48 → 3.06 ± 1.1, is one track's pull, the share within ±1.2 0.865 both), the
same 3 of 3,000 tracks fail as before (none of 1,500); minimum bias (30 events, ν = 7.6,
seed 31, truth pattern, 8,343 tracks): 8,317 instead of 8,316 fitted (one long track whose
fit failed now has χ²/ndf 25), χ²/ndf medians long 0.903, upstream 1.021, VELO-only 0.991 as
before. The fit takes ×0.86 the CPU time (gsf_components sample, 946 tracks, 5 interleaved
rounds against 5ec4d3a: 3.25–3.33 → 2.77–2.90 ms per track, medians 3.28 → 2.82); telescope
electrons (`benchmarks/vs_acts.py`, 2,000 tracks): 536 → 471 µs per track, 0.49 → 0.46 ×
ACTS's GSF, q/p pull core 0.586, x pull core 0.988 and δ(q/p) core 2.059 % unchanged. Other
factors (3 interleaved rounds each): 4: ×0.885, unchanged within 1.3 σ; 3: ×0.825, within
1.5 σ on seed 11 except the beamline share within ±1.2 (0.790 → 0.787 ± 0.001); 2: ×0.74 but
the first-hit and beamline pull cores narrower by 0.11 ± 0.03 and 0.13 ± 0.03 and the
last-hit δp/p core wider (2.85 → 3.73 ± 0.24 %, seed 7): a family left with two components
on average loses the radiation tail's shape; 1 (each family to one component where it can):
×1.3 the time of all at once (4 rounds; the mixtures it leaves make every later stage
costlier). ``sibling_merge=0`` gives the previous reduction bit for bit. Profile after
(perf, JIT symbol map, a run with its sample generation): `_reduce` 27 % of the samples (the
61 → 12 reductions of the smoothing's products and the 42 → 12 after the siblings),
`_combine` 9 %, the RK4 of the non-lead components 6 %, `_merge_siblings` 4 %, material 3 %.

Reduction of the smoothing's products likewise (`GSFOptions.product_merge`, 2): the
forward × backward products that share a component of the more precise filter (the smaller
weighted mean q/p variance, `_qop_variance`) differ only by the other filter's, much wider,
component, and are merged among themselves first (`_merge_siblings`, the candidates listed
family by family) down to 2 × 12 = 24, then the closest pairs of all. With the sibling
reduction (3.5): ×0.93 the CPU time (4 interleaved rounds, 2.86 → 2.66 ms per track,
medians; factor 1: ×0.91), the electron_fits GSF rows unchanged (seed 7, 1,500 tracks: every
difference ≤ 0.001 in pull RMS, share, core and ≤ 3e−5 in δp/p core, the last-hit pull RMS
2.270 → 2.193 ± 0.067, its tail; seed 11, 3,000 tracks: the largest the beamline pull
core, 0.736 → 0.734 ± 0.001). Grouping by the *forward* component alone (×0.95) made the
last-VELO-hit q/p pull core 0.063 → 0.202 ± 0.020 and its δp/p core 0.97 → 2.35 %: there the
backward filter is the precise one, and products of one forward component carry its distinct
q/p hypotheses. ``product_merge=0`` gives the previous smoothing bit for bit. Both
reductions together (the defaults): ×0.81 the CPU time against 5ec4d3a (gsf_components
sample, 946 tracks, 5 interleaved rounds, best of 2 each: 3.21–3.44 → 2.59–2.75 ms per
track, medians 3.31 → 2.67); telescope electrons (`benchmarks/vs_acts.py`, 2,000 tracks)
536 → 462 µs per track, 0.49 → 0.45 × ACTS's GSF, q/p pull core 0.586, x pull core 0.988,
δ(q/p) core 2.059 % unchanged; minimum bias (the sample above) 8,317 of 8,343 fitted as with
the sibling reduction alone, χ²/ndf medians long 0.903, upstream 1.021 as before, 635
outliers removed on the 7,203 long tracks instead of 629.

Issue 18.2, fourth round, outputs bitwise identical (node states, covariances, χ², node χ²,
status, component counts, passes and kept q/p mixtures of the 946 lhcb-like electron tracks
below, output "core"; of 40 events' tracks with outputs "mode" and "mean"). Profile before
(perf, JIT symbol map, the fits only): `_reduce` 25 %, `_merge_siblings` 16 %, `_combine` 12
%, the RK4 of the non-lead components 10 %, the lead's Jacobian 5 %, material 5 %, exp 5 %,
`_normalise_and_cut` 3 %, log 2 %. (1) The mode search (`_mode_component`, n² exponentials
per smoothed node) passes over a component whose density cannot reach the best one (its
terms so far plus the heights w_j/√v_j of the rest): 17 % of the exponentials remain on the
kept mixtures, 1.84 → 1.13 µs per call; (2) the smoothing takes log a_i once per forward
component instead of once per pair, the "core" output each component's density term once
instead of three times, the Bethe–Heitler evaluation ln t_min and ln t_max once per plane
(`bethe_heitler_components_logs`). Together ×0.98 (`benchmarks/gsf_components.py` sample,
946 tracks, 12 components; main and this tree alternating in two processes, CPU time, best
of 2 per round, 6 rounds: medians 2.66 → 2.63 ms per track, minima 2.61 → 2.56; 5 of 6
rounds faster). (3) `_first_min`, the search of every row of `_reduce` and of the families
of `_merge_siblings`, without branches at all: its four lanes were combined by `or`/`and`,
whose short circuits the compiler made branches on which lane holds the minimum (data, so
mispredicted), and its `while` loop's tail wrapped negative indices; ×0.75–0.88 per 42 → 12
reduction, ×0.78 per 24 → 12 (with (1)–(2) ×0.91 against a main that had moved by a seeding
commit meanwhile). (4) The weight cut (`_normalise_and_cut`) decides with bitwise operators
(×0.73 on 92 components, a third below the cut), and the smoothing's family merges take each
family's closest pair row by row without branches (`_closest_siblings_by_rows`; kept branchy
after a convolution, where it was slower). (1)–(4) together against e1b2a3d (the same
protocol, 6 rounds): ×0.873, medians 2.74 → 2.39 ms per track, minima 2.69 → 2.35, every
round ×0.855–0.885; outputs bitwise e1b2a3d's also with 4 and 16 components (40 events) and
for the telescope electrons (`benchmarks/vs_acts.py`-like sample, 60 events). The acceptance
target of issue 18.2 (≤ 1 ms per track) is not reached. Profile after (3) (perf, the fits
only): `_reduce` 20 %, `_merge_siblings` 17 %, `_combine` 16 %, the RK4 of the non-lead
components 11 %, material 6 %, the lead's Jacobian 6 %, exp 4 %, `_transport` 3 %, the
weight cut 3 %. Tried and not kept (bitwise identical merges, synthetic lhcb-like mixtures):
`_merge_siblings` with a record per component of its closest later sibling, updated per
merge instead of recomputing the family's K(K − 1)/2 distances (5.05 → 5.22 µs per 92 → 42
reduction: per merge the moment matching, 25 ns, and the branches cost more than the ≤ 28
distances); `_reduce` with a renaming loop without the list of components to search again
(counted instead, then found by a scan): 9.06 → 8.90 µs per 42 → 12, 3.60 → 3.70 µs per 24 →
12 (the reduction has no hot spot left: a flat profile over ~7 passes of the remaining
components per merge, ~220 ns per merge); `_pair_product` with the substitution's columns
innermost (74 ns per product either way); `_closest_siblings` without branches after a
convolution too (×1.2–1.5 slower there on synthetic families of ≤ 8). ``product_merge=1``
(the products of one component of the more precise filter down to 12, no reduction of all
pairs after): ×0.982 (5 interleaved rounds), `benchmarks/electron_fits.py` GSF rows within
1σ of the paired-bootstrap errors on seed 7 (1,500 tracks) but the last-UT-hit q/p pull core
0.970 → 0.973 ± 0.002 on seed 11 (3,000 tracks; every δp/p core within 1σ): not made the
default.

Measurement update: each component gets its own Kalman update (sequential scalar
updates, as the Kalman core) and its weight is multiplied by its predictive likelihood
N(r_c; 0, S_c), then the weights are renormalised and cut.

Forward and backward passes, and the smoothing. The forward GSF runs from the seed at
the first node. The backward GSF is an independent filter from the last node upstream,
started from a vague prior — diag(400 mm², 400 mm², 0.01, 0.01, (0.1·q/p)²) centred at
the forward filter's final (collapsed) state. The smoothed state at node k < last is
the product of the forward *predicted* mixture (everything upstream of k) and the
backward *filtered* mixture (node k and everything downstream): every pair (i, j) gives
a component with weight ∝ a_i·b_j·N(μ_i; ν_j, P_i + B_j) and the Gaussian product's
mean and covariance; pairs below the weight cut are dropped (the pair weights come first,
from one Cholesky substitution each; the products only for the pairs kept, `_combine`)
and the product is reduced like any mixture — the GSF analogue of the Kalman core's weighted mean (for one
component exactly that). At the last node the smoothed mixture *is* the forward
filtered one, which is used as it is.

Smoothing at the written nodes (issue 18.2). The mixture product above is made where a
state is written: at the first node (the first-hit and beamline states) and the last (free),
and at every node with `GSFOptions.mixture_smoothing_everywhere`
(``--gsf-mixture-smoothing-everywhere``), or where `track_states` or the kept q/p mixtures
ask for it. At the other nodes the state serves the outlier search only (`find_outlier`'s
node χ²), and it is the product of the more precise filter's mixture (the smaller mean q/p
variance, `_qop_variance`, as the product families above) with the other filter's mixture
collapsed to one Gaussian (`_combine_moments`): ≤ 12 pairs and no reduction instead of ≤ 144
pairs, ~61 products and two reductions. Fits of one component (no bremsstrahlung, VELO-only
tracks) are bitwise those of the mixture product at every node; so are the written states of
every track whose outlier removals are the same. `track_states` and the kept mixtures take the
mixture product at every node for what they keep, but the outlier search takes the same node
states as without them, so that they change no result. Where the product with the other
filter's moments fails, or gives a non-positive variance, the node takes the mixture product
(one minimum-bias track of 4,158, seed 31, had failed that way: tests/fit/data/
gsf_moments_product_fails.npz). Measured (2026-12-07, both ways in one process,
`max_outliers` 2):

- CPU time: ×0.709 (`benchmarks/side_by_side.py --workload gsf --events 60 --rounds 6`
  against 039a7a5, 571 lhcb-like electrons, 12 components: medians 3.59 → 2.64 ms per track
  on a slow machine state, every round ×0.66–0.79); the electron gun below ×0.705, the
  minimum-bias truth tracks ×0.730. The mixture product at every node had been ~40 % of the
  fit (an ablation writing the collapsed forward prediction at those nodes instead: ×0.61).
- lhcb-like electron gun 2–50 GeV (seed 7, 1,500 truth tracks): 22 tracks (1.5 %) have other
  outlier removals (130 instead of 137 hits) and other written states; every other track's
  states and χ² are bitwise equal. q/p pulls and δp/p (`benchmarks/electron_fits.py`'s
  summary): first hit pull RMS 0.989 both, core 0.677 → 0.669, δp/p core 14.78 → 14.84 %;
  beamline RMS 1.023 both; last hit RMS 2.187 both, within ±1.2 0.899 both, δp/p central 68 %
  14.95 → 14.96 %.
- minimum bias ν = 7.6 (seed 31, 15 events, 4,158 truth tracks, fitted as electrons): 143
  tracks (3.4 %) differ; outliers 418 → 316 hits, all of them the particle's own hits here;
  χ²/ndf median 0.905 → 0.909.
- minimum bias ν = 7.6 through the triplet pattern (`pkf reconstruct --fitter gsf
  --track-states`, 12 events, 3,749 tracks): outliers removed on real tracks 78 foreign +
  230 own hits → 73 foreign + 194 own; foreign hits left on real tracks 785 → 790 of ~89,400;
  χ²/ndf median real 0.923 → 0.924, ghosts 1.012 → 1.009.
- The node states between (not written) are the collapsed approximation: at the last UT hit
  the δp/p core is 0.366 % instead of the mixture product's 0.310 % (`tests/fit/test_gsf.py`
  judges the mixture smoother there with the option on).

Tried and not kept (2026-12-07, later session), with the smoothing above:
- A Bethe–Heitler mixture of 6 components, fitted on t ≤ 0.05 (maximum CDF difference 0.0067;
  0.0020–0.0023 at the lhcb-like planes' t ≈ 0.01, where the shipped 8 components give
  0.0008): ×0.997 the CPU time (electron gun seed 7, 1,500 tracks, best of 3 interleaved), and
  the first-hit q/p pull core 0.669 → 0.556, the last-hit pull RMS 2.19 → 2.54. After the
  sibling merge to 42 components the number of Bethe–Heitler components sets at most ~6 % of
  the cost (two of the 8 components split into identical halves, 24 more children and sibling
  merges per plane: ×1.064, `benchmarks/side_by_side.py --workload gsf`, 4 rounds).
- One convolution for consecutive planes without a hit (the Bethe–Heitler distribution of
  t₁ + t₂ is that of both planes, exactly): between their first and last hit the electrons of
  that sample cross the active area of 29.7 planes and have 28.4 nodes, so 2.3 convolutions
  per track and direction could be saved, too few to pay for the approximation.
- `_reduce` on 2,614 captured 42 → 12 reductions (the forward predictions of 300 lhcb-like
  electron tracks, convolved, cut and sibling-merged as in the fit): 10.5 µs each, of which
  3.1 µs are the first nearest neighbours (74 ns per row: the row alone 12 ns, its
  `_first_min` alone 26 ns, the two together 54 ns: probably the scalar reads of a row just
  stored by vector stores waiting for them) and ~240 ns per merge. The half matrix, each distance also offered to
  the column's record in the same loop: ×1.17; the row's minimum without storing the row (the
  distances computed in `_first_min`'s four lanes): ×1.16. Both merged bitwise the same pairs.

Two priors that are not measurements (measured with the probability integral transform,
PIT = CDF of the smoothed q/p mixture at the true q/p, which is uniform and whose
Φ⁻¹-transform has unit width for a calibrated posterior; `qop_mixture_cdf`):
- The backward prior is needed (moment form) but its q/p width is information the
  product counts. 10 % is narrow enough to keep the backward RK4 through the magnet
  linear (at 100 % the lhcb-like last-UT-hit δp/p core is 19 % wider), but at the last
  node it cut off the forward mixture's bremsstrahlung tail (last-hit PIT width 1.35–1.48
  on lhcb-like, 1.15–1.19 in the telescope with 3 % X0 planes); the forward filtered
  mixture there has no prior at all (PIT width 0.97–1.05).
- For a track the magnet does not measure (VELO-only, upstream: ``batch.track_type``
  not long), the backward prior's 10 % q/p width was information the hits do not have:
  on VELO-only tracks, whose q/p is a momentum assumption (`pkf.fit.seed.velo_qop_prior`),
  the written q/p error was 0.05× the assumption's (median; minimum bias ν = 7.6, truth
  pattern), on upstream tracks the q/p pull RMS 3.0 (reference Kalman 1.3). Their backward
  prior has a q/p width BACKWARD_VAGUE_QOP_SCALE (100) × the seed's, so that the smoothed
  q/p is the forward filter's. (They do not cross the magnet, whose linearisation needs the
  10 %.) Not so for VELO-only tracks (`QOP_PRIOR_ONLY`): with a free q/p the backward mean
  drifts with the VELO's weak field to momenta far from the assumption, its scattering
  noise with it, and the first-hit tx variance came out 2.9× the reference Kalman fit's
  (median; 10 %/90 %: 1.2×/22×; tx error 4× wider at p > 3 GeV; minimum bias ν = 7.6,
  seed 31). They keep the 10 % backward prior (tx variance 0.99× the reference's) and
  their smoothed q/p block is the forward prediction's — the momentum assumption and its
  variance, uncorrelated with x, y, tx, ty (the hits carry no q/p information there).
  Both filters also zero their q/p cross-covariances before every update
  (`_decouple_qop`), so that no update moves q/p: through the VELO's few-mT fringe field
  a wrong hit's kink was absorbed by moving q/p by factors (median 14 %, up to 1.65× between
  first and last hit with a 0.5 mm kink at the first hit), and the scattering noise with it
  (first-hit tx pulls of 10³ on 6 of 2,197 real minimum-bias VELO-only candidates, whose
  Kalman-fit pulls were 3–40).
- A VELO-only track (``batch.track_type`` velo) is fitted as one Gaussian, without the
  Bethe–Heitler convolution (`gsf_fitter`'s `single_gaussian`): its q/p is the seed's
  multiple-scattering momentum (`pkf.fit.seed.velo_momentum_estimate`), which measures the
  average scattering along the track, radiation included, and the field-free VELO gives the
  hits no way to tell the components apart. Convolving counted the radiation twice: the
  low-momentum components' extra scattering noise made the first-hit tx/ty pull cores
  0.91/0.92 on the real VELO-only tracks of minimum bias (60 events at ν = 7.6, seed 31).
- The seed's q/p comes from a fit of all hits, the magnet's measurement with a 10 %
  width: used as the forward filter's prior it was counted twice, and pulled every
  node upstream of the magnet to "no loss" (lhcb-like last-VELO-hit PIT width 1.7–1.8).
  With bremsstrahlung modelled the forward filter therefore starts with the seed's q/p
  width widened to `seed_qop_fraction`·|q/p| (1.0): the seed's q/p is the linearisation
  point only (PIT width 1.05–1.06 there; δp/p at the last UT hit unchanged). Without,
  the seed is kept as the Kalman fitters keep it (its weight against the magnet's
  measurement is ≈ 0.2 %), so that the GSF equals the Kalman fit.

Relinearisation. The seed's q/p is the momentum the magnet (or the VELO→UT kink) measures,
after the radiation upstream of it; at the first hit an electron that radiated had more.
The forward filter starts from the seed, so its scattering noise between the first hit and
the magnet was that of too low a momentum, and its χ² increments too small: real upstream
electrons χ²/ndf 0.75 (electron gun 0.3–6 GeV, truth tracks; 0.85 on the real upstream
electrons of 600 minimum-bias events), with the true first-hit q/p as the seed 1.19. As the
Kalman fitters' second pass does, a fit whose first-hit momentum (the output state) came out
more than RELINEARISE_QOP_CHANGE (10 %) above the seed's is repeated from that q/p (the same
prior width, `seed_qop_fraction`): upstream χ²/ndf 0.75 → 0.98, long 1.60 → 0.90 (medians
0.69 → 0.91, 0.82 → 0.85), pulls and PIT at the first and last hit unchanged within
0.01–0.02 (same sample); `benchmarks/electron_fits.py` unchanged (first hit pull RMS 0.986,
80 % within ±1.2; beamline 1.021, 79 %; last-UT-hit δp/p core 0.315 %). Only that direction:
a first fit that came out *below* the seed's momentum is a fluctuation or a track the model
does not describe, not radiation, and repeating it from there made one electron of 1,500
(39 → 4.1 → 0.5 GeV in two hard radiations) come out 1,600σ off at its last VELO hit. A second
pass from every track gives the same χ² (0.935 upstream) at twice the cost; seeding from the
electron-hypothesis Kalman fit's first-hit q/p recovers only part (0.83). Repeated: 28 % of
the long and 63 % of the upstream electrons; of pions through the GSF, 6 % of the long and
61 % of the upstream tracks. `GsfResult.passes` says which.

Fallback. The widened prior leaves the forward filter's q/p upstream of the magnet to the
VELO and the UT alone. On a low-momentum track with a large slope one UT hit that fluctuates
by 1σ can then pull every component to a momentum that curls away in the magnet, whose field
grows with |y| (a 2.43 GeV π⁻ with ty = −0.25 through the GSF, the default triplet pattern:
its one UT hit took all components from 2.35 to ≤ 1.48 GeV, and at |y| ≈ 2 m each of them
left the envelope); the fit failed ("extrapolation failed") where the Kalman fitters fit the
track. A fit whose extrapolation failed is therefore repeated with the seed's own q/p width,
the prior of the Kalman fitters and of the GSF without bremsstrahlung (`narrow_ctx`,
`GsfResult.passes` 3). On those tracks the magnet's q/p is counted twice upstream of it (see
above); every other track's fit is unchanged, bit for bit. Measured (2026-12-07):
- minimum bias ν = 7.6 through the triplet pattern (`pkf reconstruct --fitter gsf`, 20
  events, seed 31): 5,779 → 5,780 of 5,780 tracks fitted (the reference Kalman fit and the
  GX2F: 5,780); the recovered track (a real long track) χ²/ndf 0.72, beamline, first- and
  last-hit pulls within ±1.02; every other row of the χ² table identical;
- Pythia minimum bias ν = 3 (10 events, seed 5): 1,068 → 1,069 of 1,069; the track above
  (tests/fit/data/gsf_wide_prior_curls.npz) χ²/ndf 0.95, first-hit pulls x, y, tx, ty −1.07,
  −1.58, 0.44, 2.38 where the reference Kalman fit's are −1.06, −1.56, 0.42, 2.31 (a scattered
  track), q/p 0.08;
- minimum bias truth tracks (15 events, seed 31, 4,158 tracks): 7 → 5 extrapolation failures.
  The reference Kalman fit fails on the same 5: their least-squares seeds (`pkf.fit.seed`) are
  23–56 % below the true momentum (|ty| 0.19–0.29, 1.0–2.2 GeV), and every field-map fit
  curls at the seed's q/p. The triplet pattern's seeds carry the pattern's q/p instead.

Output per node (`output`):
- "core" (default): the centre of the Gaussian core of the smoothed q/p marginal — three
  passes of moment matching within ±3σ (`_core`), the fit `pkf.report.gauss` makes of a
  sample, started from the peak below — with x, y, tx, ty from the mixture conditional
  on q/p there (the δp/p core of this centre is the narrowest of the four outputs).
- "mode": the peak — the component at whose q/p the q/p marginal density is highest,
  merged by moment matching with the components not resolved from it (|μ_j − μ_m| ≤
  `peak_window`·√(v_j + v_m) in q/p, window 1).
  For both, where the mixture's q/p second moment about the written q/p,
  Σ w_c·(v_c + (μ_c − q)²), is wider than the core's (peak's) variance, the written
  covariance is the mixture's second moment about the written state,
  Σ w_c·(P_c + (μ_c − x)(μ_c − x)ᵀ) (`widen_to_mixture`), applied after the last fit
  (`_gsf_end`; the outlier removal uses the core's own). The core's width is that of the electrons that
  did not radiate where the detector cannot see it: on lhcb-like, where ~80 % radiate
  between the first hit and the magnet (no field there), it claimed 1 % where the error
  is 30 % (issue 15; first-hit q/p pull RMS 51, 25 % within ±1.2, electron gun 2–50 GeV,
  1,500 tracks). With the second moment: RMS 0.99, 80 % within ±1.2 (beamline 1.02,
  79 %); the pulls' Gaussian core is then narrower than 1 (0.65) because the posterior
  is skewed: a peak and a long radiation tail.
- "max-weight": ACTS' choice: the largest-weight component's mean, with the mixture's
  covariance about it.
- "mean": the mixture's mean and full covariance (moment matching).
χ² is the sum over nodes of the forward filter's predicted-residual χ² of the collapsed
predicted mixture (for one component: the Kalman fitters' χ²), ndf = Σ measurement
dimensions − 5. Outliers are removed by the Kalman core's rule (`find_outlier`), by each
node's standardised χ² of the output state (where a mixture covariance exceeds the
measurement variance, standardised by the measurement variance alone).

What a GSF can and cannot do (measured, issue 7): a GSF narrows the Gaussian *core* of
δp/p only where the momentum is measured across material in which most electrons
radiate more than the resolution. Telescope, 10 pixel planes over 1 m: 3 % X0 planes in
2 T (an ATLAS-like budget, 0.3 X0) core −30…−40 % at the first hit with q/p pull cores
0.97–1.05 (five samples); 3 % in 1 T −12…−25 %; the built-in 1 % planes in 1 T ±4 % (half the
electrons lose less than the 2 % resolution there, and for them the Kalman fit is
already optimal) while the RMS drops by 40 %. In the lhcb-like spectrometer the
momentum is measured in the magnet, which holds no material: at the last UT hit (the
state the magnet measures) GSF and Kalman fit agree (core ratio 0.92–1.02, both
calibrated); the bremsstrahlung between the first hit and the magnet (≈ 0.25 X0, almost
no field) is not observable, so no fit measures the first-hit q/p; downstream, the
SciFi radiation (0.12 X0) is seen only through the fringe field: the last-hit central
68 % is 6–26 % narrower than the Kalman fit's (six samples) with calibrated pulls, but its Gaussian
core is wider (the Kalman fit's narrow core there is the no-radiation hypothesis, right
for the ~45 % who do not radiate, with q/p pulls 4.4–6.4). Just downstream of the
magnet (first SciFi hit) the posterior is too wide (PIT width 0.6; 0.4/0.54/0.72 with
4/8/16 components: the KL reduction of the 12 × 12 product merges distinct hypotheses).

Cost. Each component's mean is transported by RK4; by default (`share_jacobians`) the
RK4 Jacobian is integrated for the largest-weight component and shared by the
components whose bends over the transport differ from its own by at most
`JACOBIAN_SHARE_KICK` = 0.03 rad; the others group around a few anchors in q/p, each
with its own Jacobian (`_share_jacobians`). The transport Jacobian of a z-parametrised
state depends on q/p through the bend (the (1 + t²) factors and the slopes along the
path), and the bends scale with q/p: in the VELO every component takes the lead's,
through the magnet the hard-radiation hypotheses do not. Sharing saves the 4 extra field
evaluations per stage and the Jacobian algebra per component. With
``share_jacobians=False`` every component integrates its own. Until 2026-12 every
component took the lead's Jacobian: through the magnet a sub-GeV hypothesis of a 2 GeV
track moved by the 2 GeV Jacobian, the last-hit q/p differed from the per-component
Jacobians' fit by 0.104σ RMS, and a track whose mixture spans a factor of several in q/p
changed its fit discontinuously with 1e−9 changes of its Bethe–Heitler mixture (the
heap-corruption track of tests/fit/test_gsf.py: χ² 102.37, 102.64, 104.4 or failed,
against 61.27 with per-component Jacobians; now 61.62 whatever the perturbation).
Measured (the `benchmarks/gsf_components.py` sample, 60 events, 571 tracks, 12
components, every rule in one process, alternating, min of 12 rounds of CPU time; q/p
differences to the per-component Jacobians' fit in units of its σ, RMS over the 570
tracks every rule fits):

| Jacobian shared within | ms per track | Δ(q/p) first hit | Δ(q/p) last hit | failed |
|---|---|---|---|---|
| all (the lead's) | 3.18 | 0.038σ | 0.104σ | 1 |
| 0.1 rad | 3.37 | 0.024σ | 0.013σ | 0 |
| 0.03 rad (default) | 3.37 | 0.009σ | 0.007σ | 0 |
| 0.01 rad | 3.55 | 0.017σ | 0.004σ | 0 |
| none (``share_jacobians=False``) | 3.97 | 0 | 0 | 0 |

The first-hit q/p pull core (0.668–0.679) and δp/p core (14.54–14.76 %) agree within
their statistical errors for every rule. Earlier measurements (`python benchmarks/gsf_components.py --events 100
--repeat 3`, lhcb-like electrons, one loaded 2-core machine): 1.5 / 3.7 / 6.2 / 9.1 ms
per track with at most 4 / 8 / 12 / 16 components (≈ n^1.3), 8.9 ms at 12 with a
Jacobian per component, 0.24 ms for the reference Kalman fit (efa2332); after issue 18.2
(below; wall time, the 2 cores shared with two other jobs) 1.31 / 2.86 / 4.89 / 7.28 ms,
7.35 ms with a Jacobian per component, 0.16 ms for the reference Kalman fit. Sharing changes the output
states by 0.005σ (x, y, tx, ty) and 0.13σ (q/p) RMS at the first hit, up to 0.26σ in q/p
at the last hit (the KL reduction follows small differences), with the same resolutions.

Where the time goes (issue 18.2; CPU time per stage from a clock around it, 30 events of
the gsf_components electron sample, 29.5 nodes and ~64 convolutions per track, forward and
backward): at 6.2 ms per track (efa2332) transport 16 %, material and Bethe–Heitler
convolution 8 %, the 64 reductions after a convolution (64 → 12 components after the
weight cut) 30 %, the 30 forward × backward products (144 pairs → 133 candidates → 61
kept by the weight cut → 12) 26 % for the pairs and 18 % for their reduction and output,
updates 1 %. Two changes, with outputs equal up to rounding (≤ 2e−8σ on the benchmark
samples; electron_fits.py's pull and δp/p figures equal to 8 digits; 60 minimum-bias
events ν = 7.6 seed 31: the same 16,540 of 16,546 tracks ok, χ² equal to 1.4e−9 on 99.9 %
of them, and one ghost track, 10/258, whose refit after its first UT outlier had a negative
residual variance at the next UT hit before — χ² NaN, unseen by the outlier search — and
now removes it as a second outlier, χ² 48): the reduction's neighbour searches are rows
of distances without branches over contiguous q/p moments, which the compiler vectorises, on a mixture
kept compact while it shrinks (rows of 38 instead of 64 on average; ×1.5 per reduction);
the pair weights take one equilibrated Cholesky factor and one forward substitution, the
products (P − XᵀX, X = L⁻¹·D·P) only the kept pairs (×1.8). Now 4.4–4.5 ms per track
on the `benchmarks/gsf_components.py` sample (946 tracks; separate processes alternating with
efa2332, CPU time, best of 2 × 2: 6.03 → 4.46 ms, ×0.74), telescope electrons
(`benchmarks/vs_acts.py` sample, 2,000 tracks) 0.99 → 0.63 ms (×0.63).
Split now (the same clock, ±3 %): transport 22 %, material 12 %, reductions after a
convolution 28 %, pairs 20 %, their reduction 12 % and output 4 %. The RK4 of the components other than the
leading one is 18 % of the total (ablated, not moved at all: 4.43 → 3.62 ms), most of it
in the magnet (the 5 m between UT and SciFi are 52 steps of 100 mm for each component);
moving the components by the leading one's Jacobian where the field bends them apart by
less than 1e−5 rad (the VELO) together with one Bethe–Heitler evaluation per plane
changed the time by −3…+1 % (within the machine's noise) and is not done.

Issue 18.2, three changes with bitwise identical outputs (states, covariances, χ², node χ²,
component counts, passes, kept q/p mixtures and per-stage states of 946 lhcb-like
electron tracks with every output and 4/12/16 components, with and without shared
Jacobians, and of the telescope electrons): (1) the GSF's track loop and kernels run
without numba's reference counting (`pkf.jit.NO_REFCOUNT`; the fitter registered with
``allocates=False``, as the Kalman core and the GX2F): perf with a map of the JIT
symbols had 23 % of all samples on the two atomic instructions of NRT_incref/decref
(×0.78); (2) the smoothing keeps each candidate pair's Cholesky factor, scales and
substitution from its weight for its product instead of factorising the kept pairs
again, takes log b_j once per backward component and exp(log weight − largest) once
per candidate and cut, and the mode search each √v once (×0.95); (3) the reduction's
nearest-neighbour searches (`_first_min`) take the smallest distance in four
interleaved running minima without branches and then its first index (×0.92). lhcb-like
electrons (`benchmarks/gsf_components.py` sample, 946 tracks, 12 components; main and
this tree alternating in two processes, CPU time, best of 2 per round, 6 rounds, a
loaded machine): 4.96–5.17 → 3.35–3.58 ms per track (×0.69 per round, median);
telescope electrons (`benchmarks/vs_acts.py` sample, 200 events, 2,000 tracks, 6 rounds
of best of 3): 0.72–0.79 → 0.49–0.54 ms (×0.68). Profile after (perf, the same JIT
symbol map): `_reduce` 36 % of the samples of a run (sample generation included),
`_combine` 8 %, the field map 9 %. Tried and not kept: the initial neighbour search
over each pair once (the distance is symmetric bit for bit, but offering each row to the
later components costs more than the half row saves: ×1.1–1.2 slower on the
reduction), fusing the distance row with the search or the offers (slower), per-lane
first indices in `_first_min` with a branch for the offers (×0.90 on the reduction
alone, ×0.993 on the fit: within the noise).

Issue 18.2, second round, outputs bitwise identical again (the same 163 arrays, and
`benchmarks/electron_fits.py`'s JSON), each change timed against the one before (lhcb-like
electrons, 946 tracks, 6 interleaved rounds, CPU time, medians): (1) `_reduce` lists the
components that search again while it renames the records instead of scanning for them
afterwards, and `_first_min` keeps a first index per lane (one pass without branches
instead of a minimum and a scan) — ×0.91 per reduction on realistic 64 → 12 mixtures
(19.2 → 17.5 µs); the field lookup (`field_at`, `_map_at`) is inlined into the RK4
stages: together ×0.952 (3.51 → 3.33 ms against cc35fa3); (2) the smoothing's pair sums,
Cholesky factors and substitutions run side by side over all pairs (`_pair_sums`,
`_pair_factors`, `_pair_solves`: ×0.82 on 12 × 12 synthetic mixtures), ×0.967 (the
backward mixture has fewer components near the last node); (3) the components other
than the lead move through the field map side by side (`_move_others`,
`pkf.physics.transport.rk4_propagate_map_many`: the z part of each stage's lookup once
for all, lookups without branches; ×0.72 on the RK4 alone), ×0.969.
Profile after (2) (perf, JIT symbol map, fit samples only): `_reduce` 52 %, RK4 of the
components with the inlined field map 12 %, `_combine` 11 %, the lead's Jacobian 4 %,
material and Bethe–Heitler 5 %, exp/log 5 %, `_normalise_and_cut` 3 %. The reduction
stays the cost: ~120 per track (64 after a convolution, 30 of the products, forward and
backward, ×1.28 passes), each 64 → 12 in 52 merges of ~7 vectorised passes over the
~38 remaining components. Tried and not kept (micro-benchmarks, bitwise identical
merges, µs per 64 → 12 reduction against 17.5): the merge step fused into one pass
(rename, distances, offers, the next pick: 20.7, the compiler does not vectorise it),
each row's distances and minimum in one pass without storing the row (21.4), the offers
fused with the next pick (17.2–17.5: within the noise), eight lanes in `_first_min` (no
faster). A pruned search in q/p order (the KL distance is at least (Δq)²/v_i, also in
floating point) would shorten the searches again but not the offers, which every merge
needs over all components.

Numerical failures. The kernels are compiled with numba's ``error_model="numpy"``: a
division by zero gives ±inf or NaN instead of raising ZeroDivisionError (which aborted
the whole run, issue 13), and a track whose output state, covariance or χ² is not
finite gets a failure status ("covariance not positive definite").

For a hypothesis other than the electron (no bremsstrahlung), the mixture keeps one
component and the GSF is a Kalman filter with forward filter, independent backward
filter and weighted-mean combination (tested to equal the Kalman core).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numba as nb
import numpy as np

from pkf.fit.options import GSFOptions
from pkf.fit.driver import max_nodes, register_fitter
from pkf.fit.kalman import NodeStages, node_stages, scalar_update
from pkf.physics.linalg import copy5, copy55, sandwich, set_identity
from pkf.fit.propagate import add_plane_material, in_envelope, plane_path_x0, propagator, register_actor
from pkf.fit.reference import ReferenceExtrapolator, reference_extrapolator
from pkf.fit.seed import TRACK_LONG, TRACK_VELO
from pkf.geometry.field import FIELD_MAP
from pkf.fit.status import STATUS_EXTRAPOLATION_FAILED, STATUS_NO_SEED, STATUS_NOT_POSITIVE_DEFINITE, STATUS_OK
from pkf.fit.tracks import FitResult, collect_track_states, fit_locations, run_fitter
from pkf.jit import NO_REFCOUNT
from pkf.params.bethe_heitler import (
    BetheHeitlerMixture,
    bethe_heitler_components_logs,
    load_bethe_heitler_mixture,
)
from pkf.physics.transport import rk4_propagate_map_many, rk4_propagate_scalar, rk4_transport_jacobian
from pkf.physics.constants import MASS_ELECTRON

OUTPUT_CORE = 3
OUTPUT_MODE = 0
OUTPUT_MEAN = 1
OUTPUT_MAX_WEIGHT = 2
#: The kernel's code of each `GSFOptions.output` name.
OUTPUTS = {"core": OUTPUT_CORE, "mode": OUTPUT_MODE, "mean": OUTPUT_MEAN, "max-weight": OUTPUT_MAX_WEIGHT}
#: Variance of a unit Gaussian truncated to ±3σ: the "core" output's window (as `pkf.report.gauss`).
_CORE_WINDOW = 3.0
_CORE_TRUNCATED_VARIANCE = 1.0 - 2.0 * _CORE_WINDOW * math.exp(-0.5 * _CORE_WINDOW**2) / math.sqrt(
    2.0 * math.pi) / math.erf(_CORE_WINDOW / math.sqrt(2.0))
#: Components of one plane whose paths t (in X0) agree within this relative tolerance share
#: one Bethe–Heitler mixture (`_material`): it moves the mixture's mean loss by ~1e-4 of
#: itself, ~1e-6 of the energy at x/X0 = 0.01.
BH_SHARED_T_TOLERANCE = 1e-4
#: With shared Jacobians, components share one only where their bends over the transport
#: differ by at most this [rad] (`_share_jacobians`; module docstring, "Cost").
JACOBIAN_SHARE_KICK = 0.03
#: Vague prior of the backward filter (see the module docstring).
BACKWARD_PRIOR_VARIANCES = (400.0, 400.0, 0.01, 0.01)
BACKWARD_PRIOR_QOP_FRACTION = 0.1
#: Backward prior of upstream tracks (they do not cross the magnet): q/p width this many
#: times the seed's (module docstring).
BACKWARD_VAGUE_QOP_SCALE = 100.0
#: Per-track q/p treatment of the backward prior (`GsfFitter.qop_prior_kind`): the 10 %
#: prior (long tracks), the vague one (upstream), or the 10 % prior with the smoothed q/p
#: block replaced by the forward prediction's (VELO-only: q/p is the momentum assumption).
QOP_MEASURED, QOP_VAGUE, QOP_PRIOR_ONLY = 0, 1, 2
#: The forward filter's seed has a q/p width of at least this fraction of |q/p| (module docstring).
SEED_QOP_FRACTION = 1.0
#: "mode" output: components within this many σ (in q/p) of the mode component form the peak.
PEAK_WINDOW = 1.0
#: A track whose first fit moved its first-hit q/p by more than this fraction of the seed's
#: is fitted again from that q/p (module docstring, "Relinearisation").
RELINEARISE_QOP_CHANGE = 0.1
_LOG_2PI = math.log(2.0 * math.pi)


class GsfExtrapolator(NamedTuple):
    """Context of the GSF: the reference extrapolator (field map, material, mass
    hypothesis), the Bethe–Heitler mixture coefficients and t range [X0], whether
    bremsstrahlung is modelled, and the mixture options."""

    ref: ReferenceExtrapolator
    bh_coefficients: np.ndarray
    bh_t_min: float
    bh_t_max: float
    bethe_heitler: bool
    max_components: int
    weight_cut: float
    output: int
    share_jacobians: bool
    seed_qop_fraction: float
    peak_window: float
    sibling_target: int
    product_target: int
    bh_shared_t_tolerance: float
    jacobian_share_kick: float
    mixture_smoothing_everywhere: bool


def gsf_extrapolator(geometry, mass: float = MASS_ELECTRON, bethe_heitler: bool | None = None,
                     share_jacobians: bool = True, mixture: BetheHeitlerMixture | None = None,
                     seed_qop_fraction: float = SEED_QOP_FRACTION, peak_window: float = PEAK_WINDOW,
                     field=None, bh_shared_t_tolerance: float = BH_SHARED_T_TOLERANCE,
                     jacobian_share_kick: float = JACOBIAN_SHARE_KICK) -> GsfExtrapolator:
    """The GSF context for `geometry`: mass hypothesis [MeV] (bremsstrahlung modelled by
    default only for the electron mass), Jacobian sharing, the Bethe–Heitler mixture
    (the shipped one by default), the least q/p width of the forward filter's seed (as a
    fraction of |q/p|), the "mode" output's peak window (see the module docstring) and the
    relative tolerance within which the components of a plane share a Bethe–Heitler mixture
    (`_material`; 0: each its own, exactly equal paths only). The
    mixture options (largest number of components, weight cut, output) are fit options
    (`GSFOptions`, `--max-components`, `--gsf-weight-cut`, `--gsf-output`), set by
    `fit_batch_gsf`; the context carries their defaults."""
    if bethe_heitler is None:
        bethe_heitler = abs(mass - MASS_ELECTRON) < 1e-6
    mixture = mixture or load_bethe_heitler_mixture()
    defaults = GSFOptions()
    return GsfExtrapolator(reference_extrapolator(geometry, mass=mass, field=field),
                           np.ascontiguousarray(mixture.coefficients), float(mixture.t_min),
                           float(mixture.t_max), bool(bethe_heitler), defaults.max_components,
                           defaults.weight_cut, OUTPUTS[defaults.output], bool(share_jacobians),
                           float(seed_qop_fraction), float(peak_window), sibling_target(defaults),
                           product_target(defaults), float(bh_shared_t_tolerance), float(jacobian_share_kick),
                           bool(defaults.mixture_smoothing_everywhere))


def sibling_target(options: GSFOptions) -> int:
    """The component count down to which siblings are merged first after a Bethe–Heitler
    convolution (`_merge_siblings`): `options.sibling_merge` × `options.max_components`,
    rounded (0: off)."""
    return int(round(options.sibling_merge * options.max_components))


def product_target(options: GSFOptions) -> int:
    """The component count down to which the smoothing's products of one component of the
    more precise filter are merged first (`_combine`): `options.product_merge` ×
    `options.max_components`, rounded (0: off)."""
    return int(round(options.product_merge * options.max_components))


@dataclass
class GsfResult(FitResult):
    """`FitResult` plus, per track, the number of components of the smoothed mixture at
    the first hit (after reduction), the passes of its last fit (1, or 2 when relinearised; 3:
    fitted again with the seed's own q/p width after its extrapolation failed, the fallback),
    and, if kept, every node's smoothed q/p mixture."""

    n_components: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    qop_mixture: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 3)))
    passes: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))


# ----------------------------------------------------------------------------------
# Mixture utilities
# ----------------------------------------------------------------------------------


@nb.njit(cache=True, error_model="numpy", inline="always", **NO_REFCOUNT)
def _copy_component(w, mu, cov, i, w2, mu2, cov2, j):
    w2[j] = w[i]
    copy5(mu[i], mu2[j])
    copy55(cov[i], cov2[j])


@nb.njit(cache=True, error_model="numpy", inline="always", **NO_REFCOUNT)
def _merge_into(w, mu, cov, i, j):
    """Component i ← moment-matched merge of components i and j."""
    wi = w[i]
    wj = w[j]
    wt = wi + wj
    if not wt > 0.0:
        return
    a = wi / wt
    b = wj / wt
    for k in range(5):
        dk = mu[i, k] - mu[j, k]
        for l in range(5):
            cov[i, k, l] = a * cov[i, k, l] + b * cov[j, k, l] + a * b * dk * (mu[i, l] - mu[j, l])
    for k in range(5):
        mu[i, k] = a * mu[i, k] + b * mu[j, k]
    w[i] = wt


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _normalise_and_cut(w, mu, cov, n, cut, labels=None):
    """Normalise the weights, drop components below `cut` (keeping the largest), compact
    (`labels`, if given, along with the components). Returns the new number of components
    (0 if no weight is positive)."""
    total = 0.0
    best = -1
    for c in range(n):
        if w[c] > 0.0 and math.isfinite(w[c]):
            total += w[c]
            if best < 0 or w[c] > w[best]:
                best = c
        else:
            w[c] = 0.0
    if not total > 0.0:
        return 0
    kept = 0.0
    for c in range(n):  # bitwise operators: the short circuits were branches on the data (the cut)
        keep = ((w[c] > 0.0) & (w[c] / total >= cut)) | (c == best)
        kept += w[c] if keep else 0.0
    out = 0
    for c in range(n):
        if ((w[c] > 0.0) & (w[c] / total >= cut)) | (c == best):
            if out != c:
                _copy_component(w, mu, cov, c, w, mu, cov, out)
                if labels is not None:
                    labels[out] = labels[c]
            w[out] /= kept
            out += 1
    return out


@nb.njit(cache=True, error_model="numpy", inline="always", **NO_REFCOUNT)
def _kl_from_moments(q, v, iv, i, j):
    """Symmetric Kullback–Leibler distance of the q/p marginals of components i and j (as
    ACTS): (v_i − v_j)(1/v_j − 1/v_i) + (q_i − q_j)²(1/v_i + 1/v_j), from their q/p means q,
    variances v and inverse variances iv = 1/v."""
    d = q[i] - q[j]
    return (v[i] - v[j]) * (iv[j] - iv[i]) + d * d * (iv[i] + iv[j])


@nb.njit(cache=True, error_model="numpy", inline="always", **NO_REFCOUNT)
def _load_qop_moments(mu, cov, k, q, v, iv):
    """Component k's q/p mean, variance and inverse variance into q, v, iv."""
    q[k] = mu[k, 4]
    v[k] = cov[k, 4, 4]
    iv[k] = 1.0 / v[k]


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _closer(d, best_d, best, candidate):
    """One offer to a nearest-neighbour search: (d, candidate) if d < best_d, else
    (best_d, best) (strict: the first of equal distances stays). Scalars in and out: the
    earlier helpers that wrote the neighbour arrays themselves made the GSF ×2.6 slower."""
    if d < best_d:
        return d, candidate
    return best_d, best


@nb.njit(cache=True, error_model="numpy", inline="always", **NO_REFCOUNT)
def _kl_row(i, n, q, v, iv, dist):
    """dist[k] ← the KL distance of components i and k (`_kl_from_moments`, bitwise) for
    every k ≠ i among the first n, +inf for i: one loop without branches over contiguous
    arrays, which the compiler vectorises (the mixture is compact: every slot is live)."""
    qi = q[i]
    vi = v[i]
    ivi = iv[i]
    for k in range(n):
        d = qi - q[k]
        dist[k] = (vi - v[k]) * (iv[k] - ivi) + d * d * (ivi + iv[k])
    dist[i] = np.inf


@nb.njit(cache=True, error_model="numpy", inline="always", **NO_REFCOUNT)
def _precedes(d, k, best_d, best):
    """(d, k) if it precedes (best_d, best) — a smaller distance, or an equal one at a
    smaller index — else (best_d, best); NaN never precedes. Bitwise operators, not `or`
    and `and`: their short circuits were branches, which the predictor missed (the lane
    that holds the minimum is data)."""
    c = (d < best_d) | ((d == best_d) & (k < best))
    return (d if c else best_d), (k if c else best)


@nb.njit(cache=True, error_model="numpy", inline="always", **NO_REFCOUNT)
def _first_min(n, dist):
    """(smallest value, its first index) of dist[:n] ((inf, −1) if none is below +inf;
    NaN never wins): what `_closer` offered the values in index order gives. One pass
    without branches: four interleaved running minima, each with the first index where
    it was reached (strict <, so the first of equal values stays), then the four combined
    by value and, for equal values, by index (`_precedes`, without branches). The branchy
    single pass was ×1.2 slower in `_reduce` (64–100 components); the two passes before (the
    minimum, then a scan for its first index, whose exit the branch predictor misses) were
    slower too (with the orphan list of `_reduce`, ×0.91 per reduction together). Eight
    lanes instead of four: no faster (17.7 against 17.3 µs per reduction). The lanes run
    over blocks of four (`range`, so the compiler knows the indices are not negative: the
    `while` loop before had a wrap-around of negative indices in its tail) and the last
    n mod 4 values join lane 0; with `_precedes` without branches, ×0.75–0.88 per 42 → 12
    reduction (9.3 → 7.0 µs, minima of 9 alternating rounds; medians of the ratio 0.88) and
    ×0.78 per 24 → 12 (issue 18.2, fourth round)."""
    m0 = np.inf
    m1 = np.inf
    m2 = np.inf
    m3 = np.inf
    i0 = -1
    i1 = -1
    i2 = -1
    i3 = -1
    for block in range(n // 4):
        k = 4 * block
        x0 = dist[k]
        x1 = dist[k + 1]
        x2 = dist[k + 2]
        x3 = dist[k + 3]
        c0 = x0 < m0
        c1 = x1 < m1
        c2 = x2 < m2
        c3 = x3 < m3
        m0 = x0 if c0 else m0
        m1 = x1 if c1 else m1
        m2 = x2 if c2 else m2
        m3 = x3 if c3 else m3
        i0 = k if c0 else i0
        i1 = k + 1 if c1 else i1
        i2 = k + 2 if c2 else i2
        i3 = k + 3 if c3 else i3
    for k in range(n - n % 4, n):
        x0 = dist[k]
        c0 = x0 < m0
        m0 = x0 if c0 else m0
        i0 = k if c0 else i0
    m0, i0 = _precedes(m1, i1, m0, i0)
    m0, i0 = _precedes(m2, i2, m0, i0)
    return _precedes(m3, i3, m0, i0)


@nb.njit(cache=True, error_model="numpy", inline="always", **NO_REFCOUNT)
def _move_component(w, mu, cov, moments, nearest, src, dst):
    """Component src, its q/p moments and its nearest-neighbour record into slot dst."""
    _copy_component(w, mu, cov, src, w, mu, cov, dst)
    for r in range(4):
        moments[r, dst] = moments[r, src]
    nearest[dst] = nearest[src]


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _reduce(w, mu, cov, n, max_n, nearest, moments):
    """Merge the closest pairs (KL distance on q/p) until at most max_n components remain;
    returns the new count (the components stay compact in the first slots). `moments`
    (5, ≥ n) is scratch: the nearest distance of each component, its q/p mean, variance
    and inverse variance, and one row of distances, kept contiguous so that a distance
    costs no division and no strided load; `nearest` (2, ≥ n) int: each component's
    nearest neighbour (the mixture stays compact: every slot up to the count is live) and
    the list of the components whose neighbour was merged away.

    Nearest-neighbour bookkeeping: every component knows its nearest neighbour; the pair
    merged is the component with the smallest such distance and its neighbour (the
    first index among equal distances); after a merge, the merged component's distances
    to all others are one row (`_kl_row`), which also offers it as the new neighbour of
    each component it is now closer to, and the components whose neighbour was one of
    the merged pair search again (one row each). Every row is a loop without branches,
    which the compiler vectorises, and the mixture stays compact while it shrinks: the
    last component fills the slot of the one merged away, so that every row runs over
    the remaining components only (64 → 12 on lhcb-like electrons: rows of 38 on
    average instead of 64). The pairs merged are those of merging in place (02cf0ed's
    bookkeeping) except among exactly equal distances; the order of the surviving
    components, and with it the rounding of later sums over them, differs. The components
    that search again are listed while their records are renamed (no second scan of the
    records, whose branch the predictor missed): with `_first_min` in one pass ×0.91 on
    realistic mixtures (64 → 12, 19.2 → 17.5 µs per reduction), the same merges."""
    if n <= max_n:
        return n
    nn = nearest[0]
    orphans = nearest[1]
    nearest_d, q, v, iv, dist = moments[0], moments[1], moments[2], moments[3], moments[4]
    for i in range(n):
        _load_qop_moments(mu, cov, i, q, v, iv)
    for i in range(n):
        _kl_row(i, n, q, v, iv, dist)
        nearest_d[i], nn[i] = _first_min(n, dist)
    count = n
    while count > max_n:
        i = max(_first_min(count, nearest_d)[1], 0)  # the first smallest (the first if none is finite)
        j = nn[i]
        if j < 0:  # no comparable distance (a NaN variance): merge with any other, never stop short
            j = 1 if i == 0 else 0
        _merge_into(w, mu, cov, i, j)
        _load_qop_moments(mu, cov, i, q, v, iv)
        last = count - 1
        count -= 1
        n_orphans = 0
        for k in range(count + 1):  # -2: the neighbour was merged, search again; last → j (moved below)
            t = nn[k]
            lost = t == i or t == j
            nn[k] = -2 if lost else (j if t == last else t)
            orphans[n_orphans] = k
            n_orphans += 1 if lost else 0
        if j != last:  # the last component fills the slot of j
            _move_component(w, mu, cov, moments, nn, last, j)
            if i == last:
                i = j
        for r in range(n_orphans):
            k = orphans[r]
            if k == j:
                continue  # merged away (its slot holds the last component, or is past the count)
            if k == last:
                k = j
            if k != i:
                _kl_row(k, count, q, v, iv, dist)
                nearest_d[k], nn[k] = _first_min(count, dist)
        _kl_row(i, count, q, v, iv, dist)
        near_d, near = _first_min(count, dist)
        for k in range(count):
            closer = dist[k] < nearest_d[k]
            nearest_d[k] = dist[k] if closer else nearest_d[k]
            nn[k] = i if closer else nn[k]
        nearest_d[i] = near_d
        nn[i] = near
    return count


@nb.njit(cache=True, error_model="numpy", inline="always", **NO_REFCOUNT)
def _closest_siblings(lo, hi, q, v, iv, alive):
    """(KL distance, a, b) of the closest pair a < b of live components (alive > 0) among
    slots lo … hi − 1, the first in (a, b) order among equal distances; (inf, −1, −1) if
    none is below +inf (NaN never is)."""
    best = np.inf
    best_a = -1
    best_b = -1
    for a in range(lo, hi):
        if not alive[a] > 0.0:
            continue
        for b in range(a + 1, hi):
            if alive[b] > 0.0:
                d = _kl_from_moments(q, v, iv, a, b)
                if d < best:
                    best = d
                    best_a = a
                    best_b = b
    return best, best_a, best_b


@nb.njit(cache=True, error_model="numpy", inline="always", **NO_REFCOUNT)
def _closest_siblings_by_rows(lo, hi, q, v, iv, alive):
    """`_closest_siblings` (the same pair, bitwise) without branches: each row's closest later
    live component, then the rows in order (strict <, so the first pair stays). Faster on
    the smoothing's families (the products of one component, up to 12: ×0.77 per 72 → 24
    reduction of synthetic products), slower on the Bethe–Heitler families of ≤ 8 (×1.2–1.5)."""
    best = np.inf
    best_a = -1
    best_b = -1
    for a in range(lo, hi):
        qa = q[a]
        va = v[a]
        iva = iv[a]
        row = np.inf
        row_b = -1
        for b in range(a + 1, hi):
            d = qa - q[b]
            x = (va - v[b]) * (iv[b] - iva) + d * d * (iva + iv[b])
            c = (x < row) & (alive[b] > 0.0)
            row = x if c else row
            row_b = b if c else row_b
        c = (row < best) & (alive[a] > 0.0)
        best = row if c else best
        best_a = a if c else best_a
        best_b = row_b if c else best_b
    return best, best_a, best_b


@nb.njit(cache=True, error_model="numpy", inline="always", **NO_REFCOUNT)
def _closest_family_pair(lo, hi, q, v, iv, alive, by_rows):
    """`_closest_siblings_by_rows` if by_rows, else `_closest_siblings`."""
    if by_rows:
        return _closest_siblings_by_rows(lo, hi, q, v, iv, alive)
    return _closest_siblings(lo, hi, q, v, iv, alive)


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _merge_siblings(w, mu, cov, n, target, parent, nearest, moments, by_rows=False):
    """Merge the closest pair of siblings (components with the same `parent`, consecutive:
    the Bethe–Heitler children of one component, `_material`) in the KL distance of
    `_reduce` until at most `target` components remain or no sibling pair is left; returns
    the new count (compact, in the order of the survivors). Siblings share everything but
    their q/p row and column (module docstring, "Reduction after a convolution"); each family
    keeps its own closest pair (distance, slots), so a merge recomputes only that family's
    ≤ K(K − 1)/2 distances. The survivors' parents are not compacted along. `nearest` (4, ≥ n + 1) and `moments`
    (5, ≥ n) are scratch. `by_rows`: the closest pairs by `_closest_siblings_by_rows` (the
    same pairs)."""
    if n <= target:
        return n
    start, first, second = nearest[0], nearest[1], nearest[3]
    best_d, q, v, iv, alive = moments[0], moments[1], moments[2], moments[3], moments[4]
    n_families = 0
    for c in range(n):
        if c == 0 or parent[c] != parent[c - 1]:
            start[n_families] = c
            n_families += 1
        _load_qop_moments(mu, cov, c, q, v, iv)
        alive[c] = 1.0
    start[n_families] = n
    for f in range(n_families):
        best_d[f], first[f], second[f] = _closest_family_pair(start[f], start[f + 1], q, v, iv, alive, by_rows)
    count = n
    while count > target:
        f = _first_min(n_families, best_d)[1]
        if f < 0:
            break
        i = first[f]
        _merge_into(w, mu, cov, i, second[f])
        _load_qop_moments(mu, cov, i, q, v, iv)
        alive[second[f]] = 0.0
        count -= 1
        best_d[f], first[f], second[f] = _closest_family_pair(start[f], start[f + 1], q, v, iv, alive, by_rows)
    out = 0
    for c in range(n):
        if alive[c] > 0.0:
            if out != c:
                _copy_component(w, mu, cov, c, w, mu, cov, out)
            out += 1
    return out


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _total_weight(w, n):
    """Σ w_c over the first n components, in component order."""
    total = 0.0
    for c in range(n):
        total += w[c]
    return total


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _collapse(w, mu, cov, n, out_mean, out_cov):
    """Mean and covariance of the mixture (moment matching)."""
    total = _total_weight(w, n)
    for k in range(5):
        s = 0.0
        for c in range(n):
            s += w[c] * mu[c, k]
        out_mean[k] = s / total
    _second_moment(w, mu, cov, n, out_mean, out_cov)


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _second_moment(w, mu, cov, n, centre, out_cov):
    """Covariance of the mixture about `centre`: Σ w_c·(P_c + (μ_c − centre)(μ_c − centre)ᵀ)."""
    total = _total_weight(w, n)
    for k in range(5):
        for l in range(5):
            s = 0.0
            for c in range(n):
                s += w[c] * (cov[c, k, l] + (mu[c, k] - centre[k]) * (mu[c, l] - centre[l]))
            out_cov[k, l] = s / total


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _peak(w, mu, cov, n, mode, window, out_mean, out_cov):
    """The mixture's peak around component `mode`: the moment-matched merge of the
    components whose q/p is compatible with the mode's, |μ_j − μ_m| ≤ window·√(v_j + v_m)."""
    total = 0.0
    for k in range(5):
        out_mean[k] = 0.0
    vm = cov[mode, 4, 4]
    for c in range(n):
        d = mu[c, 4] - mu[mode, 4]
        if d * d <= window * window * (cov[c, 4, 4] + vm):
            total += w[c]
            for k in range(5):
                out_mean[k] += w[c] * mu[c, k]
    for k in range(5):
        out_mean[k] /= total
    for k in range(5):
        for l in range(5):
            out_cov[k, l] = 0.0
    for c in range(n):
        d = mu[c, 4] - mu[mode, 4]
        if d * d <= window * window * (cov[c, 4, 4] + vm):
            a = w[c] / total
            for k in range(5):
                for l in range(5):
                    out_cov[k, l] += a * (cov[c, k, l] + (mu[c, k] - out_mean[k]) * (mu[c, l] - out_mean[l]))


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _largest(w, n):
    best = 0
    for c in range(1, n):
        if w[c] > w[best]:
            best = c
    return best


#: `_mode_component`: a component is passed over when its density plus the bound of the
#: terms not yet taken, times this, is below the best density (the sums' rounding is
#: below 3nε ≈ 1e−14 relative for n ≤ 100 components).
_MODE_BOUND_MARGIN = 1.0 + 1e-9


@nb.njit(cache=True, error_model="numpy", inline="always", **NO_REFCOUNT)
def _mode_term(w, mu, cov, root, c, j):
    """Component j's term of the q/p marginal density at component c's q/p mean (×√2π)."""
    v = cov[j, 4, 4]
    d = mu[c, 4] - mu[j, 4]
    return w[j] * math.exp(-0.5 * d * d / v) / root[j]


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _mode_component(w, mu, cov, n, scratch, order):
    """The component at whose q/p mean the mixture's q/p marginal density is highest (the
    first among equal densities; the first component if no density is a number).

    Each density is the sum over j, in component order, of w_j·exp(−(μ_c − μ_j)²/2v_j)/√v_j
    (`_mode_term`). Term j is at most its height h_j = w_j/√v_j (exp ≤ 1), so a component
    whose terms taken so far plus the heights of the others stay below the best density
    cannot be the mode and is passed over (bound with `_MODE_BOUND_MARGIN`, so the choice
    is that of computing every density, bitwise): the tallest component is taken first,
    every other takes its terms tallest first. On lhcb-like electrons 17 % of the n²
    exponentials remain (issue 18.2, fourth round). A density computed to the end is
    summed again in component order, as computing it directly does. `scratch` (4, ≥ n)
    and `order` (≥ n, int) are scratch."""
    root, height, suffix, term = scratch[0], scratch[1], scratch[2], scratch[3]
    bounded = True  # no negative weight (the margin is relative)
    for j in range(n):
        root[j] = math.sqrt(cov[j, 4, 4])
        h = w[j] / root[j]
        height[j] = h if h > 0.0 else 0.0  # NaN: every density is NaN, any choice passed over is right
        bounded = bounded and not w[j] < 0.0
        order[j] = j
    for a in range(1, n):  # tallest first (insertion sort; the order only decides what is passed over)
        k = order[a]
        b = a - 1
        while b >= 0 and height[order[b]] < height[k]:
            order[b + 1] = order[b]
            b -= 1
        order[b + 1] = k
    total = 0.0
    for r in range(n - 1, -1, -1):
        total += height[order[r]]
        suffix[r] = total  # Σ heights of order[r:]
    tallest = order[0]
    best = 0
    best_density = -1.0
    for step in range(n):
        c = tallest if step == 0 else step - 1 + (1 if step - 1 >= tallest else 0)
        partial = 0.0
        passed = False
        for r in range(n):
            if bounded and (partial + suffix[r]) * _MODE_BOUND_MARGIN < best_density:
                passed = True
                break
            j = order[r]
            term[j] = _mode_term(w, mu, cov, root, c, j)
            partial += term[j]
        if passed:
            continue
        density = 0.0
        for j in range(n):
            density += term[j]
        if density > best_density or (density == best_density and c < best):
            best_density = density
            best = c
    return best


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _core(w, mu, cov, n, q, var, out_mean, out_cov, density):
    """Output "core": the Gaussian core of the mixture's q/p marginal f and the other
    parameters given q/p at its centre (see the module docstring).

    Core: three passes of moment matching within q ± 3σ, starting from (q, var) [1/MeV,
    1/MeV²] — window mass M0 = Σ_c w_c·(Φ(b_c) − Φ(a_c)) and first two moments of f there
    (a_c, b_c the window edges in component c's σ), then q ← mean, σ² ← variance / 0.9733
    (the variance of a ±3σ-truncated Gaussian), the fit `pkf.report.gauss` makes of a
    sample. The others: responsibilities r_c ∝ w_c·N(q; μ_c, v_c); conditional means
    m_c = μ_c + P_c[:, 4]/v_c·(q − μ_c) and covariances P_c − P_c[:, 4]P_c[4, :]/v_c,
    slopes β = Σ r_c P_c[:, 4]/v_c; output x = Σ r_c m_c, C_xx = Σ r_c (conditional
    covariance + (m_c − x)(m_c − x)ᵀ) + ββᵀσ², C_xq = βσ², C_qq = σ². One component:
    exactly that component. `density` (≥ n) is scratch: each component's w_c·N(q; μ_c, v_c)·√(2π),
    taken once for the sum and both passes over the components."""
    if n == 1:
        copy5(mu[0], out_mean)
        copy55(cov[0], out_cov)
        return
    inv_sqrt_2pi = 1.0 / math.sqrt(2.0 * math.pi)
    for _ in range(3):
        sig = math.sqrt(var)
        m0 = 0.0
        m1 = 0.0
        m2 = 0.0
        for c in range(n):
            sc = math.sqrt(cov[c, 4, 4])
            u = mu[c, 4] - q
            a = (-_CORE_WINDOW * sig - u) / sc
            b = (_CORE_WINDOW * sig - u) / sc
            e0 = 0.5 * (math.erfc(-b / math.sqrt(2.0)) - math.erfc(-a / math.sqrt(2.0)))
            pa = math.exp(-0.5 * a * a) * inv_sqrt_2pi
            pb = math.exp(-0.5 * b * b) * inv_sqrt_2pi
            e1 = pa - pb  # window moments of a unit Gaussian: ∫z φ, ∫z² φ = e0 + a·pa − b·pb
            e2 = e0 + a * pa - b * pb
            m0 += w[c] * e0
            m1 += w[c] * (u * e0 + sc * e1)
            m2 += w[c] * (u * u * e0 + 2.0 * u * sc * e1 + sc * sc * e2)
        if not m0 > 0.0:
            break
        d = m1 / m0
        v = m2 / m0 - d * d
        if not v > 0.0:
            break
        q += d
        var = v / _CORE_TRUNCATED_VARIANCE
    total = 0.0
    for c in range(n):
        d = q - mu[c, 4]
        density[c] = w[c] * math.exp(-0.5 * d * d / cov[c, 4, 4]) / math.sqrt(cov[c, 4, 4])
        total += density[c]
    for i in range(5):
        out_mean[i] = 0.0
        for j in range(5):
            out_cov[i, j] = 0.0
    beta = out_cov[4]  # row 4 holds β until the end
    for c in range(n):
        vc = cov[c, 4, 4]
        d = q - mu[c, 4]
        r = density[c] / total
        for i in range(4):
            out_mean[i] += r * (mu[c, i] + cov[c, i, 4] / vc * d)
            beta[i] += r * cov[c, i, 4] / vc
    for c in range(n):
        vc = cov[c, 4, 4]
        d = q - mu[c, 4]
        r = density[c] / total
        for i in range(4):
            di = mu[c, i] + cov[c, i, 4] / vc * d - out_mean[i]
            for j in range(4):
                dj = mu[c, j] + cov[c, j, 4] / vc * d - out_mean[j]
                out_cov[i, j] += r * (cov[c, i, j] - cov[c, i, 4] * cov[c, j, 4] / vc + di * dj)
    for i in range(4):
        for j in range(4):
            out_cov[i, j] += beta[i] * beta[j] * var
    for i in range(4):
        out_cov[i, 4] = beta[i] * var
        out_cov[4, i] = beta[i] * var
    out_cov[4, 4] = var
    out_mean[4] = q


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def widen_to_mixture(cov, mixture_cov):
    """Write the smoothed mixture's covariance about the written state, `mixture_cov`
    (5×5, `_second_moment`), over `cov` (the core's or the peak's) where its q/p variance
    is the wider: the written error then covers the radiation tail in every parameter the
    tail moves, as far as the mixture moves it.

    Before, only the q/p variance was the mixture's and x, y, tx, ty given q/p were kept
    (C_ij += C_iq·C_jq·(s − 1)/C_qq, C_iq ·= s, s = var/C_qq): that carried the tail along
    the *core's* slope C_iq/C_qq, which the components do not follow (their x means sit on
    the hits), and x, tx over-covered: telescope electrons 1–50 GeV, first-hit x/tx pull
    cores 0.80/0.73, last hit 0.50/0.39 (ACTS's whole-mixture covariance: x 0.97). Keeping
    the core's x, y, tx, ty block instead under-covered the tails (tx pull RMS 1.46 at the
    first hit, x 2.05 at the last hit of 0.3–2 GeV lhcb-like long electrons)."""
    if mixture_cov[4, 4] > cov[4, 4]:
        copy55(mixture_cov, cov)


# ----------------------------------------------------------------------------------
# Transport, material, update
# ----------------------------------------------------------------------------------


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _transport(ctx, w, mu, cov, n, z_from, z_to, seg, tmp, tmp2, work, many, anchor_jac, anchor):
    """RK4 of every component's mean from z_from to z_to, covariances by a Jacobian: with
    ctx.share_jacobians (and a leading component that stays in the envelope) shared by the
    components whose bends over the transport differ by at most ctx.jacobian_share_kick
    (`_share_jacobians`), else each its own. A component that fails (leaves the
    z-parametrised envelope, or a variance overflows) gets weight 0. Returns the number of
    surviving components. `work` (5, 5, 5) scratch: the RK stages and the leading state;
    `many` (5, ≥ n) scratch: the other components' means side by side (`_move_others`);
    `anchor_jac` (≥ n, 5, 5) and `anchor` (2, ≥ n) int: the shared Jacobians and who
    shares which (nothing is allocated)."""
    if z_to == z_from:
        return n
    ref = ctx.ref
    lead = _largest(w, n)
    alive = 0
    shared = ctx.share_jacobians
    if shared:
        new = work[4, 0]
        copy5(mu[lead], new)
        rk4_transport_jacobian(new, z_from, z_to, ref.max_step, ref.field_kind, ref.field_params, ref.field_grid,
                               seg, work[:4])
        # a lead that leaves the envelope has no Jacobian to share: each component its own
        shared = in_envelope(new) and _finite55(seg)
    if shared:
        _share_jacobians(ctx, mu, n, lead, new, z_from, z_to, work, anchor_jac, anchor)
        _move_others(ref, mu, n, lead, z_from, z_to, many)
        for i in range(4):
            mu[lead, i] = new[i]
        for c in range(n):
            a = anchor[1, c]
            sandwich(seg if a < 0 else anchor_jac[a], cov[c], tmp, tmp2)
            copy55(tmp2, cov[c])
    else:
        for c in range(n):
            rk4_transport_jacobian(mu[c], z_from, z_to, ref.max_step, ref.field_kind, ref.field_params,
                                   ref.field_grid, seg, work[:4])
            sandwich(seg, cov[c], tmp, tmp2)
            copy55(tmp2, cov[c])
    for c in range(n):
        if in_envelope(mu[c]) and _finite_diagonal(cov[c]):
            alive += 1
        else:
            w[c] = 0.0
    return alive


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _share_jacobians(ctx, mu, n, lead, lead_new, z_from, z_to, work, anchor_jac, anchor):
    """Which Jacobian each component's covariance takes from z_from to z_to (before the
    means move): anchor[1, c] = −1 the lead's, else a (anchor_jac[a], integrated from the
    first component of anchor a, whose index is anchor[0, a]).

    The transport Jacobian of a z-parametrised state depends on q/p through the bend:
    components whose bends over the transport differ by Δθ have Jacobians that differ by
    O(Δθ) (the (1 + t²) factors and the slopes along the path), while bends scale with q/p:
    Δθ = θ_lead·|Δ(q/p)|/|q/p_lead|, θ_lead the lead's change of slope (lead_new against
    mu[lead]). So a component shares the Jacobian of the lead, or of the first component
    within ctx.jacobian_share_kick [rad] of it (greedy in component order), or becomes an
    anchor with its own: every covariance is transported by a Jacobian whose bend is
    within the tolerance of its own. Sharing the lead's with every component (the
    previous rule) transported a sub-GeV hypothesis of a 2.2 GeV track through the magnet
    with the 2.2 GeV Jacobian, and the track's fit changed discontinuously with 1e-9
    changes of its Bethe–Heitler mixture (tests/fit/test_gsf.py, the heap-corruption track)."""
    lead_qop = mu[lead, 4]
    bend = math.hypot(lead_new[2] - mu[lead, 2], lead_new[3] - mu[lead, 3])
    reach = ctx.jacobian_share_kick * abs(lead_qop) / bend  # in q/p; +inf where nothing bends
    ref = ctx.ref
    start = work[4, 1]
    n_anchors = 0
    for c in range(n):
        anchor[1, c] = -1
        if c == lead or not abs(mu[c, 4] - lead_qop) > reach:
            continue
        a = 0
        while a < n_anchors and abs(mu[c, 4] - mu[anchor[0, a], 4]) > reach:
            a += 1
        if a == n_anchors:
            anchor[0, a] = c
            copy5(mu[c], start)
            rk4_transport_jacobian(start, z_from, z_to, ref.max_step, ref.field_kind, ref.field_params,
                                   ref.field_grid, anchor_jac[a], work[:4])
            n_anchors += 1
        anchor[1, c] = a


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _move_others(ref, mu, n, lead, z_from, z_to, many):
    """RK4 of the means of every component but the lead (whose Jacobian is shared) from
    z_from to z_to, x, y, tx, ty in place. Through a field map all of them side by side
    (`rk4_propagate_map_many`, bitwise as one by one; many (5, ≥ n) scratch), otherwise one
    by one (`rk4_propagate_scalar`)."""
    if ref.field_kind == FIELD_MAP:
        m = 0
        for c in range(n):
            if c != lead:
                for i in range(5):
                    many[i, m] = mu[c, i]
                m += 1
        rk4_propagate_map_many(many, m, z_from, z_to, ref.max_step, ref.field_params, ref.field_grid)
        m = 0
        for c in range(n):
            if c != lead:
                for i in range(4):
                    mu[c, i] = many[i, m]
                m += 1
        return
    for c in range(n):
        if c != lead:
            x, y, tx, ty = rk4_propagate_scalar(mu[c, 0], mu[c, 1], mu[c, 2], mu[c, 3], mu[c, 4], z_from, z_to,
                                                ref.max_step, ref.field_kind, ref.field_params, ref.field_grid)
            mu[c, 0] = x
            mu[c, 1] = y
            mu[c, 2] = tx
            mu[c, 3] = ty


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _finite55(a):
    """Whether every element of the 5×5 matrix a is finite."""
    for i in range(5):
        for j in range(5):
            if not math.isfinite(a[i, j]):
                return False
    return True


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _finite_diagonal(cov):
    """Whether the variances of the 5×5 covariance cov are finite."""
    for i in range(5):
        if not math.isfinite(cov[i, i]):
            return False
    return True


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _material(ctx, k, direction, w, mu, cov, n, w2, mu2, cov2, jm, noise, bw, bm, bv, parent):
    """Material of plane k for every component of (w, mu, cov)[:n], written into
    (w2, mu2, cov2): ionisation and scattering (`add_plane_material`), then the
    Bethe–Heitler convolution; each output component's input component into `parent` (the
    children of one component are consecutive). A component whose particle stops in the
    plane (q/p → ±inf) is dropped. Returns the number of output components (0 if every one
    stopped).

    The components' paths t through the plane differ only through their slopes, so a
    component whose t agrees with the last evaluated one within `ctx.bh_shared_t_tolerance`
    (relative, `BH_SHARED_T_TOLERANCE` by default) reuses that Bethe–Heitler mixture (bw, bm, bv) instead of evaluating its
    logarithm, exponentials and polynomials again."""
    ref = ctx.ref
    log_t_min = math.log(ctx.bh_t_min)
    log_t_max = math.log(ctx.bh_t_max)
    shared_t = -1.0  # t of the mixture now in (bw, bm, bv); none yet
    shared_count = 0
    out = 0
    for c in range(n):
        set_identity(jm)
        for i in range(5):
            for j in range(5):
                noise[i, j] = 0.0
        t = plane_path_x0(ref, k, mu[c])
        add_plane_material(ref, k, mu[c], direction, jm, noise)
        if not math.isfinite(mu[c, 4]):
            continue  # this hypothesis stops in the plane (E − ΔE ≤ m): it is dropped
        d = jm[4, 4]
        pc = cov[c]
        for i in range(5):
            pc[4, i] *= d
            pc[i, 4] *= d
        for i in range(5):
            for j in range(5):
                pc[i, j] += noise[i, j]
        nb_comp = 0
        if ctx.bethe_heitler and t > 0.0 and mu[c, 4] != 0.0 and math.isfinite(mu[c, 4]):
            if abs(t - shared_t) <= ctx.bh_shared_t_tolerance * t:
                nb_comp = shared_count
            else:
                nb_comp = bethe_heitler_components_logs(ctx.bh_coefficients, ctx.bh_t_min, ctx.bh_t_max,
                                                        log_t_min, log_t_max, t, bw, bm, bv)
                shared_t = t
                shared_count = nb_comp
        if nb_comp == 0:
            _copy_component(w, mu, cov, c, w2, mu2, cov2, out)
            parent[out] = c
            out += 1
            continue
        qop = mu[c, 4]
        for b in range(nb_comp):
            _copy_component(w, mu, cov, c, w2, mu2, cov2, out)
            w2[out] *= bw[b]
            zb = bm[b]
            if direction > 0.0:
                jq = 1.0 / zb
                new_qop = qop / zb
                add = new_qop * new_qop * bv[b] / (zb * zb)
            else:
                jq = zb
                new_qop = qop * zb
                add = qop * qop * bv[b]
            mu2[out, 4] = new_qop
            p2 = cov2[out]
            for i in range(5):
                p2[4, i] *= jq
                p2[i, 4] *= jq
            p2[4, 4] += add
            parent[out] = c
            out += 1
    return out


class MixtureMaterial(NamedTuple):
    """Propagator actor of the GSF: the mixture buf[0:3] = (w, mu, cov) with count[0]
    components, transported component by component (`_transport`); at each plane the
    material and Bethe–Heitler convolution into buf[3:6] (`_material`), the weight cut
    and the reduction to at most ctx.max_components, back into buf[0:3]. The other
    fields are `_reduce`'s bookkeeping and scratch."""

    ctx: tuple
    buf: tuple
    count: np.ndarray
    nearest: np.ndarray
    moments: np.ndarray
    scratch: np.ndarray
    bh: np.ndarray


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _mixture_transport(actor, ext, z_from, z_to, crossed):
    """RK4 of every component; the components that left the envelope are dropped."""
    w, mu, cov = actor.buf[0], actor.buf[1], actor.buf[2]
    n = actor.count[0]
    _transport(actor.ctx, w, mu, cov, n, z_from, z_to, actor.scratch[0], actor.scratch[1], actor.scratch[2],
               actor.scratch[6:11], actor.moments, actor.scratch[11:], actor.nearest[4:])
    n = _normalise_and_cut(w, mu, cov, n, 0.0)
    actor.count[0] = n
    return STATUS_OK if n > 0 else STATUS_EXTRAPOLATION_FAILED


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _mixture_interact(actor, ext, k, direction):
    """Material and Bethe–Heitler convolution of plane k, weight cut, reduction."""
    w, mu, cov, w2, mu2, cov2 = actor.buf
    ctx = actor.ctx
    parent = actor.nearest[2]
    n2 = _material(ctx, k, direction, w, mu, cov, actor.count[0], w2, mu2, cov2, actor.scratch[3],
                   actor.scratch[4], actor.bh[0], actor.bh[1], actor.bh[2], parent)
    n2 = _normalise_and_cut(w2, mu2, cov2, n2, ctx.weight_cut, parent)
    if ctx.sibling_target > 0:
        n2 = _merge_siblings(w2, mu2, cov2, n2, max(ctx.sibling_target, ctx.max_components), parent,
                             actor.nearest, actor.moments)
    n2 = _reduce(w2, mu2, cov2, n2, ctx.max_components, actor.nearest, actor.moments)
    for c in range(n2):
        _copy_component(w2, mu2, cov2, c, w, mu, cov, c)
    actor.count[0] = n2
    return STATUS_OK


register_actor(MixtureMaterial, _mixture_transport, _mixture_interact)
_propagate_mixture = propagator(_mixture_transport, _mixture_interact)


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _propagate(ctx, z_from, z_to, buf, n, count, nearest, moments, scratch, bh):
    """Transport the mixture buf[0:3] (n components) from z_from to z_to through the
    material planes in (min z, max z] (`MixtureMaterial`); buf = (w, mu, cov) × 2 working
    sets, count a 1-element scratch. Returns the new component count (0: failed)."""
    count[0] = n
    actor = MixtureMaterial(ctx, buf, count, nearest, moments, scratch, bh)
    if _propagate_mixture(ctx.ref, actor, z_from, z_to) != STATUS_OK:
        return 0
    return count[0]


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _update(w, mu, cov, n, n_meas, hx, hy, m, sigma, weight_cut):
    """Per-component Kalman update with node (n_meas, hx, hy, m, sigma) and weight
    re-scaling by the predictive likelihoods. Returns the new component count."""
    largest = -np.inf
    for c in range(n):
        loglik = 0.0
        ok = True
        for j in range(n_meas):
            inc, s = scalar_update(mu[c], cov[c], hx[j], hy[j], m[j], sigma[j] * sigma[j])
            if not s > 0.0:
                ok = False
                break
            loglik -= 0.5 * (inc + math.log(s) + _LOG_2PI)
        if ok and w[c] > 0.0:
            w[c] = math.log(w[c]) + loglik
            largest = max(largest, w[c])
        else:
            w[c] = -np.inf
    if largest == -np.inf:
        return 0
    for c in range(n):
        w[c] = math.exp(w[c] - largest) if w[c] > -np.inf else 0.0
    return _normalise_and_cut(w, mu, cov, n, weight_cut)


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _predicted_chi2(w, mu, cov, n, n_meas, hx, hy, m, sigma, mean, cmat):
    """χ² increment of the node with the collapsed predicted mixture (−1 on failure)."""
    _collapse(w, mu, cov, n, mean, cmat)
    chi2 = 0.0
    for j in range(n_meas):
        inc, s = scalar_update(mean, cmat, hx[j], hy[j], m[j], sigma[j] * sigma[j])
        if not s > 0.0:
            return -1.0
        chi2 += inc
    return chi2


@nb.njit(cache=True, error_model="numpy", inline="always", **NO_REFCOUNT)
def _pair_sums(fcov, nf, bcov, nb_, s, bt):
    """s[5k + l, p] ← (P_i + B_j)[k, l] for every pair p = i·nb + j and l ≤ k (the lower
    triangle the factor reads); bt (≥ 15 rows of ≥ nb) scratch: B_j's elements side by side."""
    for k in range(5):
        for l in range(k + 1):
            row = bt[5 * k + l]
            for j in range(nb_):
                row[j] = bcov[j, k, l]
    for k in range(5):
        for l in range(k + 1):
            src = bt[5 * k + l]
            dst = s[5 * k + l]
            for i in range(nf):
                f = fcov[i, k, l]
                o = i * nb_
                for j in range(nb_):
                    dst[o + j] = f + src[j]


@nb.njit(cache=True, error_model="numpy", inline="always", **NO_REFCOUNT)
def _pair_factors(n, s, lu, scale, ok):
    """`equilibrated_cholesky` of the n matrices s[:, p] side by side (structure of arrays:
    every loop runs over the pairs, which the compiler vectorises; each element is computed
    by the same operations in the same order, so bitwise as one by one): lu[5k + l, p] = L_kl,
    scale[k, p] = 1/√S_kk; ok[p] = 1 where S_p is positive definite, else 0 (the rest is
    then undefined)."""
    for k in range(5):
        d = s[6 * k]
        sc = scale[k]
        for p in range(n):
            good = d[p] > 0.0 and (k == 0 or ok[p] > 0.0)
            ok[p] = 1.0 if good else 0.0
            sc[p] = 1.0 / math.sqrt(d[p])
    for jj in range(5):
        djj = s[6 * jj]
        scj = scale[jj]
        ljj = lu[6 * jj]
        for p in range(n):
            ljj[p] = djj[p] * scj[p] * scj[p]
        for k in range(jj):
            lk = lu[5 * jj + k]
            for p in range(n):
                ljj[p] -= lk[p] * lk[p]
        for p in range(n):
            good = ljj[p] > 0.0 and ok[p] > 0.0
            ok[p] = 1.0 if good else 0.0
            ljj[p] = math.sqrt(ljj[p])
        for i in range(jj + 1, 5):
            a = s[5 * i + jj]
            sci = scale[i]
            lij = lu[5 * i + jj]
            for p in range(n):
                lij[p] = a[p] * sci[p] * scj[p]
            for k in range(jj):
                lik = lu[5 * i + k]
                ljk = lu[5 * jj + k]
                for p in range(n):
                    lij[p] -= lik[p] * ljk[p]
            for p in range(n):
                lij[p] = lij[p] / ljj[p]


@nb.njit(cache=True, error_model="numpy", inline="always", **NO_REFCOUNT)
def _pair_solves(fmu, nf, bmu, nb_, s, lu, scale, y, q, det, bmt):
    """`_pair_log_overlap`'s substitution of every pair side by side: y[k, p] = (L⁻¹·D·d)_k,
    d = ν_j − μ_i, q[p] = Σ y_k², det[p] = Π L_kk²·S_kk (in k order, as one by one); bmt
    (≥ 5 rows of ≥ nb) scratch."""
    n = nf * nb_
    for k in range(5):
        row = bmt[k]
        for j in range(nb_):
            row[j] = bmu[j, k]
    for p in range(n):
        q[p] = 0.0
        det[p] = 1.0
    for k in range(5):
        yk = y[k]
        sck = scale[k]
        bk = bmt[k]
        for i in range(nf):
            f = fmu[i, k]
            o = i * nb_
            for j in range(nb_):
                yk[o + j] = (bk[j] - f) * sck[o + j]
        for l in range(k):
            lkl = lu[5 * k + l]
            yl = y[l]
            for p in range(n):
                yk[p] -= lkl[p] * yl[p]
        lkk = lu[6 * k]
        skk = s[6 * k]
        for p in range(n):
            t = yk[p] / lkk[p]
            yk[p] = t
            q[p] += t * t
            det[p] *= lkk[p] * lkk[p] * skk[p]


@nb.njit(cache=True, error_model="numpy", inline="always", **NO_REFCOUNT)
def _pair_log_overlap(p, s, lu, q, det):
    """log N(μ_i; ν_j, S) + (5/2)·log 2π = −½·(dᵀS⁻¹d + log det S) of pair p from
    `_pair_solves` (q = dᵀS⁻¹d, det = det S): one logarithm of the product; the sum of
    the logarithms where it under- or overflows."""
    d = det[p]
    if d > 0.0 and math.isfinite(d):
        logdet = math.log(d)
    else:
        logdet = 0.0
        for k in range(5):
            logdet += 2.0 * math.log(lu[6 * k, p]) + math.log(s[6 * k, p])
    return -0.5 * (q[p] + logdet)


@nb.njit(cache=True, error_model="numpy", inline="always", **NO_REFCOUNT)
def _pair_product(fmu, fcov, i, lu, scale, y, p, x, out_mu, out_cov):
    """The Gaussian product of forward component i and the backward component of pair p,
    from the pair's factor (lu, scale) and substitution (y) (`_pair_factors`,
    `_pair_solves`): with X = L⁻¹·D·P_i (x, 5×5; five forward substitutions),
    P_i·S⁻¹·P_i = XᵀX and P_i·S⁻¹·d = Xᵀy, so mean μ_i + Xᵀy and covariance P_i − XᵀX
    (exactly symmetric) — the Kalman form μ_i + K·d, P_i − K·P_i with K = P_i·S⁻¹ without
    S⁻¹. False if a variance of the product is not positive."""
    for c in range(5):
        for k in range(5):
            t = fcov[i, k, c] * scale[k, p]
            for l in range(k):
                t -= lu[5 * k + l, p] * x[l, c]
            x[k, c] = t / lu[6 * k, p]
    for k in range(5):
        t = fmu[i, k]
        for r in range(5):
            t += x[r, k] * y[r, p]
        out_mu[k] = t
    ok = True
    for k in range(5):
        for l in range(k, 5):
            t = fcov[i, k, l]
            for r in range(5):
                t -= x[r, k] * x[r, l]
            out_cov[k, l] = t
            out_cov[l, k] = t
        if not out_cov[k, k] > 0.0:
            ok = False
    return ok


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _combine(ctx, fw, fmu, fcov, nf, bw, bmu, bcov, nb_, pw, pmu, pcov, plu, pvec, nearest, moments,
             out_mean, out_cov, scratch, vec):
    """Product of the forward-predicted and backward-filtered mixtures at a node into
    (pw, pmu, pcov), reduced, and the output state (`_summarise`). Returns the product's
    component count (0 on failure).

    Pairs (i, j) of positive weights whose P_i + B_j is positive definite are candidates,
    with log weight log a_i + log b_j + log N(μ_i; ν_j, P_i + B_j) (`_pair_log_overlap`).
    The sums, their equilibrated Cholesky factors and the substitutions of every pair are
    computed side by side, a structure of arrays over the nf·nb pairs (`_pair_sums`,
    `_pair_factors`, `_pair_solves`: plu (25, ≥ nf·nb) the factors, pvec (45, ≥ nf·nb)
    the rest), bitwise as pair by pair. The products' means and covariances
    (`_pair_product`) are computed only for the candidates the weight cut keeps (w/Σw ≥
    weight_cut, and the largest; on lhcb-like electrons 61 of 133), and each candidate's
    exp(log weight − largest) is taken once per cut. A candidate whose product has a
    non-positive variance is no candidate (as when every product was computed first: it
    counts neither in the largest weight nor in the sum), and the cut is made again
    without it. Equal to computing every product first (02cf0ed) up to rounding."""
    x = scratch[3]
    pair = nearest[0]
    family = nearest[2]  # each kept product's component of the more precise filter
    state = moments[0]  # 0: candidate, product not computed; 1: computed; −1: no candidate
    scaled = moments[1]  # exp(log weight − largest) of each candidate
    log_bw = moments[2]  # log b_j
    y, scale, s, ok, q, det, bmt = pvec[0:5], pvec[5:10], pvec[10:35], pvec[35], pvec[36], pvec[37], pvec[38:43]
    _pair_sums(fcov, nf, bcov, nb_, s, plu)
    _pair_factors(nf * nb_, s, plu, scale, ok)
    _pair_solves(fmu, nf, bmu, nb_, s, plu, scale, y, q, det, bmt)
    log_fw = moments[3]  # log a_i
    for j in range(nb_):
        log_bw[j] = math.log(bw[j]) if bw[j] > 0.0 else 0.0
    for i in range(nf):
        log_fw[i] = math.log(fw[i]) if fw[i] > 0.0 else 0.0
    by_backward = ctx.product_target > 0 and _qop_variance(bw, bcov, nb_) < _qop_variance(fw, fcov, nf)
    n = 0
    for a in range(nb_ if by_backward else nf):  # the candidates of one family consecutive
        for b in range(nf if by_backward else nb_):
            i = b if by_backward else a
            j = a if by_backward else b
            p = i * nb_ + j
            if not (fw[i] > 0.0 and bw[j] > 0.0 and ok[p] > 0.0):
                continue
            pw[n] = log_fw[i] + log_bw[j] + _pair_log_overlap(p, s, plu, q, det)
            if math.isnan(pw[n]):
                continue
            pair[n] = p
            state[n] = 0.0
            n += 1
    while True:  # the cut, again after a candidate's product failed
        largest = -np.inf
        best = -1
        for c in range(n):
            if state[c] >= 0.0 and pw[c] > largest:
                largest = pw[c]
                best = c
        if best < 0:
            return 0
        total = 0.0
        for c in range(n):
            scaled[c] = math.exp(pw[c] - largest)
            if state[c] >= 0.0:
                total += scaled[c]
        failed = False
        for c in range(n):
            w = scaled[c]
            if state[c] == 0.0 and (c == best or (w > 0.0 and w / total >= ctx.weight_cut)):
                p = pair[c]
                if _pair_product(fmu, fcov, p // nb_, plu, scale, y, p, x, pmu[c], pcov[c]):
                    state[c] = 1.0
                else:
                    state[c] = -1.0
                    failed = True
        if not failed:
            break
    m = 0
    for c in range(n):
        if state[c] == 1.0:
            w = scaled[c]
            if c == best or (w > 0.0 and w / total >= ctx.weight_cut):
                pw[m] = w
                family[m] = pair[c] % nb_ if by_backward else pair[c] // nb_
                if m != c:
                    copy5(pmu[c], pmu[m])
                    copy55(pcov[c], pcov[m])
                m += 1
    return _summarise(ctx, pw, pmu, pcov, m, nearest, moments, out_mean, out_cov, family)


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _combine_moments(ctx, fw, fmu, fcov, nf, bw, bmu, bcov, nb_, buf, pbuf, nearest, moments, out_mean, out_cov,
                     scratch, vec):
    """The smoothed state at a node from the more precise filter's mixture and the other's
    moments: the product (`_combine`) of the mixture of the filter with the smaller mean
    q/p variance (`_qop_variance`, as `_combine`'s families) and the other filter's mixture
    collapsed to one Gaussian (kept in slot 0 of buf[3:6], the material's scratch, free
    between transports), into pbuf[0:3] and the output state. Returns the product's component
    count (0 on failure)."""
    w1, mu1, cov1 = buf[3], buf[4], buf[5]
    pw, pmu, pcov, plu, pvec = pbuf
    w1[0] = 1.0
    if _qop_variance(bw, bcov, nb_) < _qop_variance(fw, fcov, nf):
        _collapse(fw, fmu, fcov, nf, mu1[0], cov1[0])
        return _combine(ctx, w1[0:1], mu1[0:1], cov1[0:1], 1, bw, bmu, bcov, nb_, pw, pmu, pcov, plu, pvec,
                        nearest, moments, out_mean, out_cov, scratch, vec)
    _collapse(bw, bmu, bcov, nb_, mu1[0], cov1[0])
    return _combine(ctx, fw, fmu, fcov, nf, w1[0:1], mu1[0:1], cov1[0:1], 1, pw, pmu, pcov, plu, pvec,
                    nearest, moments, out_mean, out_cov, scratch, vec)


@nb.njit(cache=True, error_model="numpy", inline="always", **NO_REFCOUNT)
def _qop_variance(w, cov, n):
    """Σ w_c·v_c / Σ w_c: the components' mean q/p variance (weighted)."""
    s = 0.0
    for c in range(n):
        s += w[c] * cov[c, 4, 4]
    return s / _total_weight(w, n)


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _summarise(ctx, w, mu, cov, n, nearest, moments, out_mean, out_cov, family=None):
    """Normalise, cut and reduce the smoothed mixture (w, mu, cov)[:n] in place and write
    its output state ("core", "mode", "max-weight" or "mean"). Returns the component count.
    With `family` (the products' families, consecutive, `_combine`) and ctx.product_target,
    the closest pairs within a family are merged first (`_merge_siblings`)."""
    n = _normalise_and_cut(w, mu, cov, n, ctx.weight_cut, family)
    if family is not None and ctx.product_target > 0:
        n = _merge_siblings(w, mu, cov, n, max(ctx.product_target, ctx.max_components), family, nearest, moments,
                            True)
    n = _reduce(w, mu, cov, n, ctx.max_components, nearest, moments)
    if ctx.output == OUTPUT_MEAN:
        _collapse(w, mu, cov, n, out_mean, out_cov)
    elif ctx.output == OUTPUT_MAX_WEIGHT:
        copy5(mu[_largest(w, n)], out_mean)
        _second_moment(w, mu, cov, n, out_mean, out_cov)
    else:
        mode = _mode_component(w, mu, cov, n, moments[:4], nearest[0])
        _peak(w, mu, cov, n, mode, ctx.peak_window, out_mean, out_cov)
        if ctx.output == OUTPUT_CORE:
            _core(w, mu, cov, n, out_mean[4], out_cov[4, 4], out_mean, out_cov, moments[0])
    return n


@nb.njit(cache=True, error_model="numpy", inline="always", **NO_REFCOUNT)
def _keep_qop_mixture(w, mu, cov, n, out):
    """Store the q/p marginal (weight, mean [1/MeV], variance) of (w, mu, cov)[:n] in out
    (K, 3) when out has rows (K ≥ n), padding with zero weights."""
    if out.shape[0] == 0:
        return
    for c in range(out.shape[0]):
        out[c, 0] = w[c] if c < n else 0.0
        out[c, 1] = mu[c, 4] if c < n else 0.0
        out[c, 2] = cov[c, 4, 4] if c < n else 1.0


# ----------------------------------------------------------------------------------
# One GSF fit of one track and the batch kernel
# ----------------------------------------------------------------------------------


@nb.njit(cache=True, error_model="numpy", inline="always", **NO_REFCOUNT)
def _decouple_qop(cov, nc):
    """A VELO-only prediction (QOP_PRIOR_ONLY): zero every component's q/p cross-covariances,
    so that the update that follows leaves its q/p (mean and variance) as it is. The hits
    carry no q/p information there, only the VELO's weak fringe field couples them: a
    wrong hit's kink was absorbed by moving q/p by factors (to 30 MeV on 42/604 of the
    minimum-bias sample), and the scattering noise of the rest of the fit with it."""
    for c in range(nc):
        for i in range(4):
            cov[c, 4, i] = 0.0
            cov[c, i, 4] = 0.0


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _prior_qop_block(fw, fmu, fcov, nf, pw, pmu, pcov, out_mean, out_cov):
    """A VELO-only node (QOP_PRIOR_ONLY): the smoothed state keeps x, y, tx, ty and takes the
    q/p mean and variance of the forward prediction (fw, fmu, fcov)[:nf] collapsed, with no
    correlation to the others; the product mixture (pw, pmu, pcov) becomes that one
    component (its q/p moments then are the written ones). Returns 1."""
    qop = 0.0
    total = 0.0
    for c in range(nf):
        qop += fw[c] * fmu[c, 4]
        total += fw[c]
    qop /= total
    var = 0.0
    for c in range(nf):
        d = fmu[c, 4] - qop
        var += fw[c] * (fcov[c, 4, 4] + d * d)
    var /= total
    out_mean[4] = qop
    for i in range(4):
        out_cov[4, i] = 0.0
        out_cov[i, 4] = 0.0
    out_cov[4, 4] = var
    pw[0] = 1.0
    copy5(out_mean, pmu[0])
    copy55(out_cov, pcov[0])
    return 1


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _valid_node_state(state, cov):
    """Whether a node's output state is finite and its variances positive."""
    for i in range(5):
        if not (cov[i, i] > 0.0 and math.isfinite(state[i])):
            return False
    return True


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _fit_track(ctx, z, n_meas, hx, hy, m, sigma, active, seed, seed_cov, fwd_w, fwd_mu, fwd_cov, fwd_n,
               buf, pbuf, count, nearest, moments, scratch, bh, vec, out_state, out_cov, out_mix,
               stages, lo, out_mixture_cov, qop_prior_kind):
    """Forward GSF, backward GSF and smoothing of one track; the smoothed mixtures' q/p
    marginals into out_mix (nodes, K, 3) if it has rows, and the means and covariances of
    the predicted, filtered and smoothed mixtures into rows lo… of `stages` (a
    `NodeStages` with smoothed rows) if it has rows, and each node's mixture second moment
    about its output state (`_second_moment`) into out_mixture_cov (n, 5, 5); `qop_prior_kind`: QOP_VAGUE, the backward
    prior's q/p width is BACKWARD_VAGUE_QOP_SCALE × the seed's (upstream); QOP_PRIOR_ONLY,
    the smoothed q/p block is the forward prediction's (VELO-only). Returns (status, χ², number of
    components of the smoothed mixture at the first node)."""
    n = z.size
    w, mu, cov = buf[0], buf[1], buf[2]
    pw, pmu, pcov, plu, pvec = pbuf
    mean = vec[15:20]
    cmat = scratch[5]
    chi2 = 0.0
    keep = out_mix.shape[0] > 0
    keep_stages = stages.predicted.shape[0] > 0
    # ---- forward filter from the seed; with bremsstrahlung its q/p width at least
    # seed_qop_fraction·|q/p| (without, the GSF is the Kalman fit with the same prior)
    w[0] = 1.0
    copy5(seed, mu[0])
    copy55(seed_cov, cov[0])
    wide = (ctx.seed_qop_fraction * seed[4]) ** 2
    if ctx.bethe_heitler and wide > cov[0, 4, 4]:
        if cov[0, 4, 4] > 0.0:
            scale = math.sqrt(wide / cov[0, 4, 4])
            for i in range(5):
                cov[0, 4, i] *= scale
                cov[0, i, 4] *= scale
        else:  # a seed without q/p variance: the widened width alone
            for i in range(5):
                cov[0, 4, i] = 0.0
                cov[0, i, 4] = 0.0
            cov[0, 4, 4] = wide
    nc = 1
    for k in range(n):
        if k > 0:
            nc = _propagate(ctx, z[k - 1], z[k], buf, nc, count, nearest, moments, scratch, bh)
            if nc == 0:
                return STATUS_EXTRAPOLATION_FAILED, chi2, 0
        if qop_prior_kind == QOP_PRIOR_ONLY:
            _decouple_qop(cov, nc)
        fwd_n[k] = nc
        for c in range(nc):
            _copy_component(w, mu, cov, c, fwd_w[k], fwd_mu[k], fwd_cov[k], c)
        if keep_stages:
            _collapse(w, mu, cov, nc, stages.predicted[lo + k], stages.predicted_cov[lo + k])
        if active[k]:
            inc = _predicted_chi2(w, mu, cov, nc, n_meas[k], hx[k], hy[k], m[k], sigma[k], mean, cmat)
            if inc < 0.0:
                return STATUS_NOT_POSITIVE_DEFINITE, chi2, 0
            chi2 += inc
            nc = _update(w, mu, cov, nc, n_meas[k], hx[k], hy[k], m[k], sigma[k], ctx.weight_cut)
            if nc == 0:
                return STATUS_NOT_POSITIVE_DEFINITE, chi2, 0
        if keep_stages:
            _collapse(w, mu, cov, nc, stages.filtered[lo + k], stages.filtered_cov[lo + k])
    # ---- the last node: the forward filtered mixture is the smoothed one
    for c in range(nc):
        _copy_component(w, mu, cov, c, pw, pmu, pcov, c)
    n_last = _summarise(ctx, pw, pmu, pcov, nc, nearest, moments, out_state[n - 1], out_cov[n - 1])
    _second_moment(pw, pmu, pcov, n_last, out_state[n - 1], out_mixture_cov[n - 1])
    if keep:
        _keep_qop_mixture(pw, pmu, pcov, n_last, out_mix[n - 1])
    if keep_stages:
        _collapse(pw, pmu, pcov, n_last, stages.smoothed[lo + n - 1], stages.smoothed_cov[lo + n - 1])
    # ---- backward filter from a vague prior at the forward filter's final state
    _collapse(w, mu, cov, nc, mean, cmat)
    w[0] = 1.0
    copy5(mean, mu[0])
    for i in range(5):
        for j in range(5):
            cov[0, i, j] = 0.0
    for i in range(4):
        cov[0, i, i] = BACKWARD_PRIOR_VARIANCES[i]
    cov[0, 4, 4] = (BACKWARD_PRIOR_QOP_FRACTION * mean[4]) ** 2
    if not cov[0, 4, 4] > 0.0:
        cov[0, 4, 4] = seed_cov[4, 4]
    if qop_prior_kind == QOP_VAGUE:
        cov[0, 4, 4] = max(cov[0, 4, 4], BACKWARD_VAGUE_QOP_SCALE**2 * seed_cov[4, 4])
    nc = 1
    n_first = n_last
    for k in range(n - 1, -1, -1):
        if k < n - 1:
            nc = _propagate(ctx, z[k + 1], z[k], buf, nc, count, nearest, moments, scratch, bh)
            if nc == 0:
                return STATUS_EXTRAPOLATION_FAILED, chi2, 0
        if qop_prior_kind == QOP_PRIOR_ONLY:
            _decouple_qop(cov, nc)
        if active[k]:
            nc = _update(w, mu, cov, nc, n_meas[k], hx[k], hy[k], m[k], sigma[k], ctx.weight_cut)
            if nc == 0:
                return STATUS_NOT_POSITIVE_DEFINITE, chi2, 0
        if k < n - 1:
            product = (k == 0 or ctx.mixture_smoothing_everywhere or qop_prior_kind == QOP_PRIOR_ONLY
                       or fwd_n[k] * nc == 1)
            if product or keep or keep_stages:
                n_node = _combine(ctx, fwd_w[k], fwd_mu[k], fwd_cov[k], fwd_n[k], w, mu, cov, nc, pw, pmu, pcov,
                                  plu, pvec, nearest, moments, out_state[k], out_cov[k], scratch, vec)
                if n_node == 0:
                    return STATUS_NOT_POSITIVE_DEFINITE, chi2, 0
                if qop_prior_kind == QOP_PRIOR_ONLY:
                    n_node = _prior_qop_block(fwd_w[k], fwd_mu[k], fwd_cov[k], fwd_n[k], pw, pmu, pcov,
                                              out_state[k], out_cov[k])
                if k == 0:
                    n_first = n_node
                if keep:
                    _keep_qop_mixture(pw, pmu, pcov, n_node, out_mix[k])
                if keep_stages:
                    _collapse(pw, pmu, pcov, n_node, stages.smoothed[lo + k], stages.smoothed_cov[lo + k])
            if not product:  # the more precise filter's mixture times the other's moments (module docstring)
                n_node = _combine_moments(ctx, fwd_w[k], fwd_mu[k], fwd_cov[k], fwd_n[k], w, mu, cov, nc, buf, pbuf,
                                          nearest, moments, out_state[k], out_cov[k], scratch, vec)
                if n_node == 0 or not _valid_node_state(out_state[k], out_cov[k]):  # the mixtures' product then
                    n_node = _combine(ctx, fwd_w[k], fwd_mu[k], fwd_cov[k], fwd_n[k], w, mu, cov, nc, pw, pmu, pcov,
                                      plu, pvec, nearest, moments, out_state[k], out_cov[k], scratch, vec)
                    if n_node == 0:
                        return STATUS_NOT_POSITIVE_DEFINITE, chi2, 0
            _second_moment(pw, pmu, pcov, n_node, out_state[k], out_mixture_cov[k])
        if not _valid_node_state(out_state[k], out_cov[k]):
            return STATUS_NOT_POSITIVE_DEFINITE, chi2, 0
    if not math.isfinite(chi2):
        return STATUS_NOT_POSITIVE_DEFINITE, chi2, 0
    return STATUS_OK, chi2, n_first


class GsfFitter(NamedTuple):
    """The GSF as a fitter of `pkf.fit.driver.fit_tracks`: its context, the per-track
    component counts, the kept q/p mixtures (nodes, K, 3; no rows: not kept), the kept
    mixture means per stage (`stages`, no rows: not kept) and scratch for the batch's
    longest track (`gsf_fitter` allocates it), among it each node's mixture second moment
    about its output (`mixture_cov`, written over the output by `_gsf_end`), each track's backward q/p prior
    (`qop_prior_kind`: QOP_MEASURED, QOP_VAGUE, QOP_PRIOR_ONLY) and those fitted as one Gaussian (`single_gaussian`, with
    `plain_ctx`: the context without the Bethe–Heitler convolution), the context whose forward filter keeps the
    seed's own q/p width (`narrow_ctx`, the fallback of `_gsf_fit`), the seed of a second pass
    (`relinearised_seed`) and each track's passes in its last fit (`out_passes`; 3: the fallback). Outliers are found with
    the measurement-only fallback: a mixture's covariance ("mean", "max-weight" outputs)
    can exceed the measurement variance."""

    ctx: tuple
    measurement_only_fallback: bool
    out_n_components: np.ndarray
    out_qop_mixture: np.ndarray
    buf: tuple
    pbuf: tuple
    fwd_w: np.ndarray
    fwd_mu: np.ndarray
    fwd_cov: np.ndarray
    fwd_n: np.ndarray
    nearest: np.ndarray
    moments: np.ndarray
    scratch: np.ndarray
    bh: np.ndarray
    vec: np.ndarray
    count: np.ndarray
    stages: NodeStages
    mixture_cov: np.ndarray
    qop_prior_kind: np.ndarray
    plain_ctx: tuple
    single_gaussian: np.ndarray
    relinearised_seed: np.ndarray
    out_passes: np.ndarray
    narrow_ctx: tuple


def gsf_fitter(ctx: GsfExtrapolator, n_nodes: int, n_tracks: int, qop_mixture: np.ndarray,
               stages: NodeStages | None = None, qop_prior_kind: np.ndarray | None = None,
               single_gaussian: np.ndarray | None = None) -> GsfFitter:
    """The GSF of context `ctx` for `n_tracks` tracks of up to `n_nodes` nodes, keeping the
    smoothed q/p mixtures in `qop_mixture` if it has rows and the mixtures' means and
    covariances per stage in `stages` if given; `qop_prior_kind` (n_tracks, int8): each
    track's QOP_MEASURED, QOP_VAGUE or QOP_PRIOR_ONLY (default: all measured); `single_gaussian` (n_tracks,
    bool): the tracks fitted without the Bethe–Heitler convolution, one Gaussian (VELO-only
    tracks, module docstring; default: none)."""
    mc = ctx.max_components
    k_bh = ctx.bh_coefficients.shape[1]
    cap = max(mc * max(k_bh, 1), mc * mc, 2)
    return GsfFitter(
        ctx, True, np.zeros(n_tracks, dtype=np.int64), qop_mixture,
        (np.zeros(cap), np.zeros((cap, 5)), np.zeros((cap, 5, 5)), np.zeros(cap), np.zeros((cap, 5)),
         np.zeros((cap, 5, 5))),
        (np.zeros(cap), np.zeros((cap, 5)), np.zeros((cap, 5, 5)), np.zeros((25, cap)), np.zeros((45, cap))),
        np.zeros((n_nodes, mc)), np.zeros((n_nodes, mc, 5)), np.zeros((n_nodes, mc, 5, 5)),
        np.zeros(n_nodes, dtype=np.int64), np.zeros((6, cap + 1), dtype=np.int64), np.zeros((5, cap)),
        np.zeros((11 + cap, 5, 5)), np.zeros((3, max(k_bh, 1))), np.zeros(20), np.zeros(1, dtype=np.int64),
        node_stages(0, smoothed=True) if stages is None else stages, np.zeros((n_nodes, 5, 5)),
        np.zeros(n_tracks, dtype=np.int8) if qop_prior_kind is None
        else np.ascontiguousarray(qop_prior_kind, dtype=np.int8),
        ctx._replace(bethe_heitler=False),
        np.zeros(n_tracks, dtype=np.bool_) if single_gaussian is None
        else np.ascontiguousarray(single_gaussian, dtype=np.bool_),
        np.zeros(5), np.zeros(n_tracks, dtype=np.int64), ctx._replace(seed_qop_fraction=0.0))


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _gsf_begin(f, t, seed):
    """STATUS_NO_SEED for a non-finite seed."""
    f.out_n_components[t] = 0
    for i in range(5):
        if not math.isfinite(seed[i]):
            return STATUS_NO_SEED
    return STATUS_OK


@nb.njit(cache=True, error_model="numpy", inline="always", **NO_REFCOUNT)
def _fit_with(f, ctx, lo, z, n_meas, hx, hy, m, sigma, active, seed, seed_cov, out_state, out_cov, out_mix, prior):
    """`_fit_track` of one track (nodes lo…) with context ctx and the fitter's scratch."""
    return _fit_track(ctx, z, n_meas, hx, hy, m, sigma, active, seed, seed_cov, f.fwd_w, f.fwd_mu, f.fwd_cov,
                      f.fwd_n, f.buf, f.pbuf, f.count, f.nearest, f.moments, f.scratch, f.bh, f.vec, out_state,
                      out_cov, out_mix, f.stages, lo, f.mixture_cov, prior)


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _gsf_fit(f, t, lo, hi, z, n_meas, hx, hy, m, sigma, active, seed, seed_cov, out_state, out_cov):
    """`_fit_track` with the fitter's scratch; the component count into out_n_components.
    With bremsstrahlung modelled, a fit whose first-hit momentum came out more than
    RELINEARISE_QOP_CHANGE above the seed's (|q/p| below (1 − 0.1)·|q/p|) is repeated from
    that q/p (module docstring, "Relinearisation"; the first fit's result is kept if the
    second fails). A fit whose extrapolation failed (every component left the envelope or
    stopped) is repeated with the seed's own q/p width (`narrow_ctx`; module docstring,
    "Fallback"): out_passes 3."""
    out_mix = f.out_qop_mixture[lo:hi] if f.out_qop_mixture.shape[0] > 0 else f.out_qop_mixture
    ctx = f.plain_ctx if f.single_gaussian[t] else f.ctx
    prior = f.qop_prior_kind[t]
    status, chi2, n_comp = _fit_with(f, ctx, lo, z, n_meas, hx, hy, m, sigma, active, seed, seed_cov, out_state,
                                     out_cov, out_mix, prior)
    f.out_passes[t] = 1
    radiated = abs(out_state[0, 4]) < (1.0 - RELINEARISE_QOP_CHANGE) * abs(seed[4])
    if status == STATUS_OK and ctx.bethe_heitler and radiated:
        copy5(seed, f.relinearised_seed)
        f.relinearised_seed[4] = out_state[0, 4]
        status2, chi2_2, n_comp2 = _fit_with(f, ctx, lo, z, n_meas, hx, hy, m, sigma, active, f.relinearised_seed,
                                             seed_cov, out_state, out_cov, out_mix, prior)
        if status2 == STATUS_OK:
            status, chi2, n_comp = status2, chi2_2, n_comp2
            f.out_passes[t] = 2
        else:  # the first fit again (its outputs were overwritten)
            status, chi2, n_comp = _fit_with(f, ctx, lo, z, n_meas, hx, hy, m, sigma, active, seed, seed_cov,
                                             out_state, out_cov, out_mix, prior)
    if status == STATUS_EXTRAPOLATION_FAILED and ctx.bethe_heitler and ctx.seed_qop_fraction > 0.0:
        status, chi2, n_comp = _fit_with(f, f.narrow_ctx, lo, z, n_meas, hx, hy, m, sigma, active, seed, seed_cov,
                                         out_state, out_cov, out_mix, prior)
        f.out_passes[t] = 3
    f.out_n_components[t] = n_comp
    return status, chi2


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _gsf_end(f, t, lo, hi, status, out_state, out_cov):
    """A failed track has NaN states and covariances. A fitted one's "core" and "mode"
    outputs get, at every node, the covariance of the whole mixture about the written
    state where its q/p variance is wider (`widen_to_mixture`; after the outlier removal,
    which used the core's own)."""
    if status != STATUS_OK:
        out_state[:] = np.nan
        out_cov[:] = np.nan
    elif f.ctx.output == OUTPUT_CORE or f.ctx.output == OUTPUT_MODE:
        for k in range(hi - lo):
            widen_to_mixture(out_cov[k], f.mixture_cov[k])


register_fitter(GsfFitter, _gsf_begin, _gsf_fit, _gsf_end, allocates=False)


def fit_batch_gsf(extrapolator: GsfExtrapolator, batch, options, seeds: np.ndarray, seed_covs: np.ndarray,
                  beamline_extrapolator=None, keep_qop_mixtures: bool = False,
                  track_states: bool = False) -> GsfResult:
    """GSF of every track of `batch` (a `TrackBatch`) with the context `extrapolator`
    (`gsf_extrapolator`), from the Kalman fitters' seeds and seed covariances.
    `options` (`FitOptions`): the outlier cut, maximum number of outliers and the mixture
    options `options.gsf` (`GSFOptions`). With `keep_qop_mixtures`, `result.qop_mixture`
    (nodes, max_components, 3) holds every node's smoothed q/p marginal (weight, mean
    [1/MeV], variance [1/MeV²]; `qop_mixture_cdf` evaluates it). With `track_states`,
    `result.track_states` holds the mean and covariance (moment matching) of the
    predicted, filtered and smoothed (reduced) mixture at every node: the smoothed mean is
    not the output state (`options.gsf.output`, "core" by default) unless the output is "mean"."""
    mixture = options.gsf
    ctx = extrapolator._replace(max_components=int(mixture.max_components), weight_cut=float(mixture.weight_cut),
                                output=OUTPUTS[mixture.output], sibling_target=sibling_target(mixture),
                                product_target=product_target(mixture),
                                mixture_smoothing_everywhere=bool(mixture.mixture_smoothing_everywhere))
    stages = node_stages(batch.z.size if track_states else 0, smoothed=True)
    velo_only = None if batch.track_type is None else batch.track_type == TRACK_VELO
    qop_prior = None if batch.track_type is None else np.where(
        velo_only, QOP_PRIOR_ONLY, np.where(batch.track_type != TRACK_LONG, QOP_VAGUE, QOP_MEASURED))
    fitter = gsf_fitter(ctx, max_nodes(batch.offsets), batch.n_tracks,
                        np.zeros((batch.z.size if keep_qop_mixtures else 0, ctx.max_components, 3)), stages, qop_prior,
                        velo_only)
    result = GsfResult.empty(batch, n_components=fitter.out_n_components, qop_mixture=fitter.out_qop_mixture,
                             passes=fitter.out_passes)
    run_fitter(fitter, batch, options, seeds, seed_covs, result)
    fit_locations(result, batch, beamline_extrapolator)
    if track_states:
        result.track_states = collect_track_states(batch, result, {
            "predicted": (stages.predicted, stages.predicted_cov), "filtered": (stages.filtered, stages.filtered_cov),
            "smoothed": (stages.smoothed, stages.smoothed_cov)})
    return result


def qop_mixture_cdf(mixture: np.ndarray, qop: np.ndarray) -> np.ndarray:
    """CDF of q/p mixtures (n, K, 3) (`GsfResult.qop_mixture` rows) at qop (n) [1/MeV]: the
    probability integral transform, uniform in [0, 1] for a calibrated posterior."""
    from scipy.special import ndtr

    w, mean, var = mixture[..., 0], mixture[..., 1], mixture[..., 2]
    return np.sum(w * ndtr((np.asarray(qop)[:, None] - mean) / np.sqrt(var)), axis=1) / np.sum(w, axis=1)

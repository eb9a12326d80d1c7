"""The envelope's geometry checks at compiled speed: the same samples, predicates and findings.

`Envelope` checks a path by sampling it (coarse to fine, `envelope.REFINEMENT`) and testing every
padded, inflated capsule at every sample against the workspace box, the keep-out zones and the
other capsules. Written with numpy over whole batches, that costs ~250 µs for one configuration
and milliseconds for one motion: a planner's budget buys a few hundred checks. Here the same work
runs in numba kernels — forward kinematics (`robot.batch_fk`'s `fk_into`, derived from the
Pinocchio model), the sampling of the path, the three checks and the refinement — with nothing
crossing back into Python until the answer is known.

**Same answer.** The kernels place the samples exactly where `sampling.samples_at` places them
(the same arithmetic, operation for operation: `unit_targets`, `searchsorted`, the linear
interpolation, `half_neighbour_bound`; the per-segment body bounds come in from numpy's own
product), give each body and pair the same inflation, check flagged samples without allowance and
refine the rest in the same depth-first order (`Envelope._refine`), and confirm every candidate
with the predicates of `safety.geometry`, ported line for line: capsule bounds in the workspace
box; the segment–box distance, and for the TCP also the slab test of its straight segment from
the previous sample; the segment–segment distance against the pair's summed radii plus its
inflation. Findings are kept per key as `Envelope` keeps them (see "findings" below), and each
returned row says what `Envelope` needs to word it: kind, body or pair, zone, time, the body's
first end point, distance, allowance. tests/safety/test_geometry_kernel.py holds compiled and
numpy envelopes to the same violations, word for word, and the same per-sample flags, on random
paths, zones and workspace boxes. (Forward kinematics agrees with Pinocchio to ~1e-15 m, not bit
for bit, so a sample lying within that of a limit could be judged differently; nothing else
differs.)

**Only faster, never weaker: the broad phases.** Per sample, each link's capsules are first
tested as one bounding sphere (fixed in the link's joint frame) grown by an upper bound of their
inflations; a link whose sphere is inside the workspace box, apart from a zone, or apart from
another link's sphere by more than the pairs' radii plus their inflation bound cannot give any of
its capsules a finding, and they are skipped. The bounds are proofs, not guesses: a body's
inflation is half its motion bound over the neighbouring sample intervals, and that bound grows
along the path at most at the rate Σ_i rate_i · reach_i, where rate_i is joint i's largest step
per unit of path parameter (`passes.joint_rates`) — and never faster than `sweep_resolution_m` per
unit, which is how the path parameter is defined; likewise a pair's relative-motion bound with
the pairs' relative reaches. A pair that survives gets the numpy pass's bounding-sphere test, a
bounding-box test against its allowance, then the exact distance — on a path first against a
bound of its inflation (its own relative-motion rate times half the sample gap), so that its
exact inflation is computed only for a pair that comes within the bound. A pair apart by a
margin is not tested again while the path parameter stays within margin ÷ rate of that sample
(its segments cannot close the margin sooner), at that sample gap or a smaller one. Margins of
1e-9 m absorb rounding in the bounds. A sample of a pass whose findings are never reported (one that only decides where to
refine) stops at its first hit; the densest pass does not test a key whose kept finding it cannot
make earlier.

**Compilation.** Like `robot.batch_fk`: eager, explicit signatures, numba's on-disk cache (or
in memory with a warning where no cache directory is writable). The first import compiles for
20–40 s (the three entry points share `sample.evaluate_sample`); later imports load the machine
code. The cache names carry a digest of every module compiled into the entry points (`jit`), so
an edit to any of them compiles afresh. The static tables (`tables.Tables`) are packed into one
int64 and one float64 array, so a call unboxes few arguments (numba's dispatcher costs about
0.1 µs per argument).

**Modules**, each depending only on those above it: `jit` (how helpers and entry points are
compiled), `tables` (the packed tables and the finding rows' layout), `predicates` (the
geometric tests), `findings` (what one check keeps and reports), `sample` (every check of one
sample), `passes` (a path, coarse to fine), `driver` (the entry points `Envelope` calls).
"""

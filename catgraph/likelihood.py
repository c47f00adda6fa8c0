r"""Training-free probability models for whole-image differences (paper 2).

A whole-image descriptor compares two frames with a single number, the difference
``d`` (SAD, cosine, Hamming …; smaller = more alike). Whether two frames show the same
place ``L`` or different places ``¬L`` changes the *distribution* of ``d``, and that
distribution is simple enough to learn from the data as it arrives.

Model
-----
Two histograms over the same ``s`` bins (``n_bins``, paper: 100) count differences
between frames of the same place, ``P(d ∧ L)``, and of different places, ``P(d ∧ ¬L)``.
Each is smoothed by mixing in the uniform distribution with weight ``ε``
(``smoothing``; additive smoothing with pseudo-counts ``α = ε N / ((1 − ε) s)``
proportional to the sample size ``N``):

.. math::

    P(b \mid L) = (1 − ε) \frac{c^L_b}{N_L} + \frac{ε}{s}, \qquad
    P(b \mid ¬L) = (1 − ε) \frac{c^{¬L}_b}{N_{¬L}} + \frac{ε}{s},

so an empty bin has a small positive probability and no ``log 0`` ever appears, and a
histogram with no samples at all is uniform (``1/s``). Because the pseudo-counts scale
with ``N``, a bin that is empty in *both* histograms carries no evidence
(``P(b|L) = P(b|¬L)``, log-likelihood ratio 0) however unequal ``N_L`` and ``N_{¬L}``
are; fixed Dirichlet pseudo-counts would instead favour the class with fewer samples
there. Densities divide by the bin
width (``P(d|L) = P(b(d)|L) / w_b``), so each integrates to one; every *ratio* below is
independent of the widths. With the prior ``P(L)`` (``prior_same``; by default the
fraction of samples that were "same place", the paper's frequency estimate)

.. math::

    P(d) = P(d \mid L) P(L) + P(d \mid ¬L) P(¬L), \qquad
    P(L \mid d) = P(d \mid L) P(L) / P(d).

Localisation against ``n`` places uses the paper's eq. (2) for each hypothesis ``i``:

.. math::

    P(L_k = L_i \mid Z^k) ∝ \frac{P(d_{ki} \mid L)}{P(d_{ki})} P(L_k = L_i \mid Z^{k-1}),

the denominator depends on ``i`` and is *not* a normalising constant. Everything is
computed in log space; :meth:`HistogramLikelihood.log_likelihood_ratio` returns
``log P(d|L) − log P(d)`` for arrays of any shape, which is what a particle filter adds
to its log-weights. The "new place" hypothesis (CAT-Graph's new-location particle) is
weighted by the average of ``P(d_s|L)/P(d_s)`` over samples ``d_s`` drawn from
``P(d|¬L)`` (eq. 10), computed either by Monte Carlo or exactly as the expectation over
the ``¬L`` histogram (:meth:`HistogramLikelihood.new_place_log_likelihood`).

Monotone likelihood ratio
-------------------------
``d`` is a difference, so a smaller value should never be less evidence of the same
place: the ratio ``P(d|L) / P(d|¬L)`` is non-increasing. With ``monotone=True`` (default)
adjacent bins that violate this are pooled: weighted isotonic regression, by pooling
adjacent violators, of ``q_b = P(b|L) / (P(b|L) + P(b|¬L))`` with weights
``P(b|L) + P(b|¬L)`` on the smoothed tables; inside a block the ratio is
``Σ P(b|L) / Σ P(b|¬L)`` and each block keeps its mass under both classes. The pooling
does not depend on ``P(L)``, and it acts only on evaluation (the counts are unchanged).

Bins and range
--------------
``range=(lo, hi)`` fixes ``s`` equal bins over ``[lo, hi]``; values outside are clipped
into the edge bins, both when learning and when evaluating. ``range=None`` (default)
adapts the range to the data *exactly reproducibly*: bins have width ``2**e`` and edges
at integer multiples of ``2**e``; ``e`` is the smallest integer (at least
``log2(min_bin_width)``) for which all differences seen so far fit into ``s`` consecutive
bins, and the window starts at the bin of the smallest difference. When new data fall
outside, ``e`` grows and neighbouring bins merge exactly (dyadic bins nest), so
``partial_fit`` in any chunks gives bit-for-bit the histogram of one ``fit`` of all the
data; between ``s/2`` and ``s`` bins carry data. Differences outside the learned window
are clipped into the edge bins when evaluated. Constant input (every ``d`` identical)
uses one bin of width ``min_bin_width``.

Three ways to learn it
----------------------
* **online, training-free** (paper §III.D, :class:`HistogramPlaceRecogniser` with the
  default ``n_init=100``): for the first ``T_init`` frames the smallest difference of
  the frame, ``d_min``, is added to ``¬L`` only (nothing is localised); afterwards each
  frame adds ``d_min`` to ``L`` and the smallest difference *outside* ``± exclusion_radius``
  reference indices of the best match (the "second-smallest difference not from the same
  location") to ``¬L``, and then localises with the histograms of that moment. The
  reference map is given, so ``d_min`` is over all reference places. By default each
  frame also adds the differences to ``n_random_different`` places drawn at random
  outside the match's location to ``¬L``: eq. (2) weighs every place, most of which have
  typical differences, and the second-smallest difference alone only describes the low
  tail of ``P(d|¬L)``. With ``reference_positions`` the match's location is every place
  within a distance of it (routes that pass a place twice) instead of an index radius.
* **trained** (:func:`labelled_samples`): ``L`` from every (query, reference) pair the
  ground truth calls a true match, ``¬L`` from a seeded subsample of the other pairs.
* **bootstrapped** from the reference map (:func:`reference_samples`): ``¬L`` from
  reference-vs-reference differences of frames more than ``gap`` indices apart; ``L`` is
  left empty (uniform: a weak prior) unless ``same_radius > 0`` asks for near-neighbour
  reference pairs. Adjacent reference frames are far more alike than the same place seen
  under other conditions, so near-neighbour ``L`` is optimistic; the default lets the
  online updates learn ``L`` from the query itself from its first frame.

Modules
-------
The model lives in :mod:`catgraph.histogram`, the choice of samples in
:mod:`catgraph.samples` and the standalone recogniser in :mod:`catgraph.recogniser`;
this module gathers their public names, so ``from catgraph.likelihood import …`` keeps
working.
"""

from __future__ import annotations

from .histogram import HistogramLikelihood, _monotone_tables
from .recogniser import HistogramPlaceRecogniser, Recognition, Recognitions
from .samples import OnlineSamples, labelled_samples, online_samples, reference_samples

__all__ = [
    "HistogramLikelihood",
    "HistogramPlaceRecogniser",
    "OnlineSamples",
    "Recognition",
    "Recognitions",
    "labelled_samples",
    "online_samples",
    "reference_samples",
]

_ = _monotone_tables  # re-exported for the models that pool likelihood ratios

"""Energy terms of one implicit Euler step, each batched over objects in the padded layout of
:class:`data_gen.sim.model.Model` (states ``tm`` (n, 3, K)).

Every term returns an :class:`~data_gen.sim.energy.terms.ObjectTerms`: energy per object (J), and when
asked, the gradient (n, 3, K) (J per unit of q) and Hessian blocks (n, 3K, 3K) in padded q-ordering.
Pair contact adds cross blocks between objects. The minimiser (:mod:`data_gen.sim.newton`) sums them.
"""

from data_gen.sim.energy.terms import ObjectTerms, PairTerms

__all__ = ["ObjectTerms", "PairTerms"]

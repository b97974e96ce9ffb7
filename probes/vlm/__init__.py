"""Vision-language model evaluation on NewtPhys question sets (docs/vqa_contract.md, evaluation protocol).

``interface`` holds the contract every answerer (Hugging Face model, served model, baseline) implements and
the on-disk layout of one run's results; the other modules build on it:

* ``specs`` (models as data), ``hf_adapter`` (the transformers adapter), ``tiny`` (random-weight test
  fixtures of real architectures), ``baselines`` (random, oracle, constant letter, prior, blind);
* ``prompting`` (items -> prompts, rotations, hashes), ``predictions`` (the resumable store), ``evaluate``
  (the loop), ``merge`` (sharded runs), ``simple_scores`` (the scorer used when ``scoring`` is absent),
  ``cli`` (``evaluate_vlm.py``).
"""

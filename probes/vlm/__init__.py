"""Vision-language model evaluation on NewtPhys question sets (docs/vqa_contract.md, evaluation protocol).

``interface`` holds the contract every answerer (Hugging Face model, served model, baseline) implements and
the on-disk layout of one run's results; the other modules build on it:

* ``specs`` (models as data), ``hf_adapter`` (the transformers adapter), ``tiny`` (random-weight test
  fixtures of real architectures), ``baselines`` (random, oracle, constant letter, prior, blind);
* ``openai_client`` (models behind an OpenAI-compatible server);
* ``prompting`` (items -> prompts, rotations, hashes), ``selection`` (which items a run asks),
  ``predictions`` (the resumable store; manifest and prediction readers), ``evaluate`` (the loop),
  ``sharding`` (whole-sequence shards and their merge), ``cli`` (``evaluate_vlm.py``);
* ``scoring`` + ``bootstrap`` (``scores.json``: macro accuracy with sequence-bootstrap intervals beside the
  trivial predictors), ``report`` (the paper's analyses, ``python -m probes.vlm_report``).
"""

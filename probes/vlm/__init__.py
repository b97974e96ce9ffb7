"""Vision-language model evaluation on NewtPhys question sets (docs/vqa_contract.md, evaluation protocol).

``interface`` holds the contract every answerer (Hugging Face model, served model, baseline) implements and
the on-disk layout of one run's results; the other modules build on it.
"""

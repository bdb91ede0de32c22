"""Research code kept apart from the product: the synthetic campus simulator (`simulation`) and
the experiments that measure the method on it (`experiments`).

The product (`pipeline`, `app`, `annotator_ui`) never imports this package, except the CLI
commands `simulate`, `demo` and `experiment`, which import it inside the command (import-linter
contract "the product never imports research" in pyproject.toml). Research imports the product:
the experiments build their data from simulated scenes and train through `pipeline.training`.
"""

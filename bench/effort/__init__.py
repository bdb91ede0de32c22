"""The operator benchmark (`python -m bench.bench_effort`): a simulated operator labels a real
recording through the service's REST API, and the exports are scored against its labels."""

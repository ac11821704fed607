"""The lab: what measures and demonstrates Garment Transfer, beside the product and never shipped.

It uses the core (``garment_transfer``) as any user would. ``python -m lab --help`` lists its commands:
the demo, the speed benchmark, the benchmark report, the held-out studies and the demo-data generator.
"""

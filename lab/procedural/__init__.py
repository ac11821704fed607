"""Procedural demo data: mannequins of one fixed topology and garments built around them."""

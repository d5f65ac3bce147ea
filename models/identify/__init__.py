"""Identification of compensation models from calibration records (`compd fit`).

The only place scipy may be imported (an import-linter contract): `compd run`
never loads it. Pure numerics: arrays in, estimates out; reading records,
hashing files and writing model files belong to `compd`.
"""

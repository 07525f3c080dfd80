"""Test doubles for the console: the example view and the fitter's laptop as a pty.

Not part of the product (the wheel never ships them); tests import them as
``from fakes.example_view import ExampleView``.
"""

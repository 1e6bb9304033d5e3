"""Odometers other than odolab's own, written only against :mod:`odolab.api`."""

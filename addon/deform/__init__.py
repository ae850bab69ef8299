# SPDX-License-Identifier: GPL-3.0-or-later
"""Pyramid Deform: settings on the object, frame evaluation, bake jobs, live playback."""

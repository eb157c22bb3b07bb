"""tactex.spectral"""

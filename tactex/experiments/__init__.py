"""tactex.experiments"""

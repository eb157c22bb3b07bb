"""tactex.sim"""

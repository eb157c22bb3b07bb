"""tactex.ergodic"""

"""tactex.geometry"""

"""tactex.perception"""

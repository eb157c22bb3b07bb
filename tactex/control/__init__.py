"""tactex.control"""

"""tactex.report"""

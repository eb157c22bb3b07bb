"""tactex.robots"""

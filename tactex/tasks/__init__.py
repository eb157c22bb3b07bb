"""tactex.tasks"""

#!/usr/bin/python3
"""Watches a parameter with rospy.get_param_cached (subscribeParam +
paramUpdate callbacks) and prints "value <v>" whenever it changes.
usage: param_watcher.py NODE_NAME PARAM"""
import sys
import time

import rospy


def main():
    name, param = sys.argv[1], sys.argv[2]
    rospy.init_node(name, anonymous=False, disable_signals=True)
    last = object()
    while not rospy.is_shutdown():
        v = rospy.get_param_cached(param, None)
        if v != last:
            sys.stdout.write("value %s\n" % (v,))
            sys.stdout.flush()
            last = v
        time.sleep(0.05)


if __name__ == "__main__":
    main()

# session 40: inclusive seconds under one function of a py-spy raw profile (between.txt, 20 Hz): python profile_tree.py FUNC DEPTH
import re, collections, sys
root = sys.argv[1]; depth = int(sys.argv[2])
tree = collections.Counter()
for line in open('between.txt'):
    line=line.rstrip()
    if not line: continue
    stack, n = line.rsplit(' ',1); n=int(n)
    names=[]
    for f in stack.split(';'):
        m = re.match(r'(.*?) \((.*?)\)$', f.strip())
        names.append(m.group(1)+' '+m.group(2).split('/')[-1] if m else f.strip())
    idx = [i for i,nm in enumerate(names) if nm.startswith(root+' ')]
    if not idx: continue
    i = idx[0]
    for d in range(1, depth+1):
        tree[tuple(names[i:i+d+1])] += n
for k,v in sorted(tree.items()):
    if v/20 >= 3: print(f"{v/20:7.1f}s " + "  "*(len(k)-1) + k[-1])

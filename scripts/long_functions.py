#!/usr/bin/env python3
"""Functions longer than a screen: every `fn` under a folder (test modules marked
`#[cfg(test)]` skipped) whose body spans more than LIMIT lines, longest first. A crude
brace matcher (strings and line comments stripped), enough to keep the rule that a
function over ~80 lines says why above it.
Usage: python3 scripts/long_functions.py src [LIMIT]"""
import re, sys, os

limit=int(sys.argv[2]) if len(sys.argv)>2 else 80
res=[]
for root,_,files in os.walk(sys.argv[1]):
  for f in files:
    if not f.endswith('.rs'): continue
    p=os.path.join(root,f); L=open(p).read().split('\n')
    intest=False
    i=0
    while i<len(L):
      line=L[i]
      if re.match(r'\s*#\[cfg\(test\)\]',line): intest=True
      m=re.match(r'\s*(pub(\([^)]*\))?\s+)?(async\s+)?(const\s+)?(unsafe\s+)?fn\s+(\w+)',line)
      if m and not intest:
        # find body start
        j=i; depth=0; started=False; k=i
        while k<len(L):
          s=re.sub(r'"(\\.|[^"\\])*"','""',L[k]); s=re.sub(r"'(\\.|[^'\\])'","''",s); s=s.split('//')[0]
          if not started and ';' in s and '{' not in s: break
          for ch in s:
            if ch=='{': depth+=1; started=True
            elif ch=='}': depth-=1
          if started and depth==0: break
          k+=1
        n=k-i+1
        if started and n>limit: res.append((n,p,i+1,m.group(6)))
      i+=1
for r in sorted(res,reverse=True): print(*r)

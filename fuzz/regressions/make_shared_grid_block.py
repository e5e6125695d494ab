"""Builds a .vdb whose N grid descriptors all point (grid_pos) at ONE shared grid block.

usage: python3 make_shared_grid_block.py SOURCE.vdb SIZE_LIMIT OUT.bin
  e.g. python3 make_shared_grid_block.py ../../fixtures/tiles.vdb 100000 read_vdb-timeout-shared-grid-block.bin
SOURCE must have grid offsets; its first grid's block is reused. Every descriptor is
accepted by VdbFile::parse and read_grid(i) decodes the whole shared tree again for
each i, so the work is (number of descriptors) x (tree size): quadratic in file size.
"""
import struct,sys
src=open(sys.argv[1],'rb').read(); limit=int(sys.argv[2]); out=sys.argv[3]
p=0
def u32():
    global p; v=struct.unpack_from('<I',src,p)[0]; p+=4; return v
def i64():
    global p; v=struct.unpack_from('<q',src,p)[0]; p+=8; return v
def s():
    global p; n=u32(); v=src[p:p+n]; p+=n; return v
assert struct.unpack_from('<Q',src,0)[0]==0x56444220
p=8; ver=u32(); u32();u32(); hgo=src[p]; p+=1
if ver<222: p+=1
p+=36
mstart=p; n=u32()
for _ in range(n): s(); s(); sz=u32(); p+=sz
header=src[:p]; gc=struct.unpack_from('<i',src,p)[0]; p+=4
name=s(); ttype=s(); parent=s(); gpos=i64(); bpos=i64(); epos=i64()
assert hgo and gc>=1, (hgo,gc)
block=src[gpos:epos]
def desc(g,b,e):
    return struct.pack('<I',0)+struct.pack('<I',len(ttype))+ttype+struct.pack('<I',0)+struct.pack('<qqq',g,b,e)
dlen=len(desc(0,0,0))
N=(limit-len(header)-4-len(block))//dlen
body=bytearray(header)+struct.pack('<i',N)
d1=len(body); G=d1+dlen; E=G+len(block)
body+=desc(G,G+(bpos-gpos),E)+block
for i in range(1,N):
    here=len(body); body+=desc(G,G+(bpos-gpos),here+dlen)
open(out,'wb').write(body); print(ttype, 'block',len(block),'grids',N,'size',len(body))

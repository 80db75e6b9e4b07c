
import numpy as np
from varint.lattice.lie import cay, cay_inv, hat, dcay_inv
rng=np.random.default_rng(1)
I=np.diag([2.,1.3,0.7]); h=0.1
xi=rng.normal(size=3)*0.7
K=lambda x: 0.5*x@I@x/h
e=1e-6
# level n+1 variation: cay(xi') = cay(xi) cay(e sig)
g1=np.array([(K(cay_inv(cay(xi)@cay(e*s)))-K(cay_inv(cay(xi)@cay(-e*s))))/(2*e) for s in np.eye(3)])
g0=np.array([(K(cay_inv(cay(-e*s)@cay(xi)))-K(cay_inv(cay(e*s)@cay(xi))))/(2*e) for s in np.eye(3)])
X=hat(xi); Ix=I@xi/h
print("D2 kin", g1, (np.eye(3)-X/2+np.outer(xi,xi)/4)@Ix)
print("-D1 kin", -g0, (np.eye(3)+X/2+np.outer(xi,xi)/4)@Ix)
# Omega variations
L0=cay(rng.normal(size=3)); L1=L0@cay(rng.normal(size=3)*0.3); ds=0.1
Om=lambda a,b: cay_inv(a.T@b)/ds
w=ds*Om(L0,L1)
J1=np.array([(Om(L0,L1@cay(e*s))-Om(L0,L1@cay(-e*s)))/(2*e) for s in np.eye(3)]).T
J0=np.array([(Om(L0@cay(e*s),L1)-Om(L0@cay(-e*s),L1))/(2*e) for s in np.eye(3)]).T
W=hat(w)
print("dOm/dsig_{j+1}", np.abs(J1-(np.eye(3)+W/2+np.outer(w,w)/4)/ds).max())
print("dOm/dsig_j", np.abs(J0+(np.eye(3)-W/2+np.outer(w,w)/4)/ds).max())
# Gamma variations
dr=rng.normal(size=3)
Ga=lambda a,b: 0.5*(a+b).T@dr/ds
G0=np.array([(Ga(L0@cay(e*s),L1)-Ga(L0@cay(-e*s),L1))/(2*e) for s in np.eye(3)]).T
print("dGa/dsig_j", np.abs(G0-0.5*hat(L0.T@dr/ds)).max())
# half(I+cay) = (I - w^/2)^-1
print("avg", np.abs(0.5*(np.eye(3)+cay(w))-np.linalg.inv(np.eye(3)-W/2)).max())

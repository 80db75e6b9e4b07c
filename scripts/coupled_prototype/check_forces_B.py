from pathlib import Path; exec((Path(__file__).parent / 'check_coupled_B.py').open().read().split("# (a) invariance")[0])
from varint.lattice.lie import dcay_inv
q1=[q0[0]+0.01*rng.normal(size=q0[0].shape),np.array([q0[1][j]@cay(0.05*rng.normal(size=3)) for j in range(N+1)]),
    q0[2]+0.001*rng.normal(size=N+1),q0[3].copy()]
q1[3][1:-1]+=0.05*ds*rng.normal(size=M-1)
def Umid(q1_):
    Om0,Ga0=strains(q0[1],q0[0]); Om1,Ga1=strains(q1_[1],q1_[0])
    return U((q0[3]+q1_[3])/2,(q0[2]+q1_[2])/2,None,(Om0+Om1)/2,(Ga0+Ga1)/2,False)
eps=1e-6
Om0,Ga0=strains(q0[1],q0[0]); Om1,Ga1=strains(q1[1],q1[0])
Omb,Gab=(Om0+Om1)/2,(Ga0+Ga1)/2; Gn=np.sqrt((Gab**2).sum(1)); gh=Gab/Gn[:,None]
sm=(q0[3]+q1[3])/2; Rm=(q0[2]+q1[2])/2
V=vols(sm,Rm,Gn); P=pres(V)
# element pressure resultant: P_e = sum_k P_k I_{k,e} - pext Vfull_e ; I_{k,e} = dV_k/d|Gamma_e| (FD)
Pe=np.zeros(N)
for e in range(N):
    G2=Gn.copy(); G2[e]+=1e-7; G3=Gn.copy(); G3[e]-=1e-7
    Ike=(vols(sm,Rm,G2)-vols(sm,Rm,G3))/2e-7
    Pe[e]=P@Ike-pext*(VolT(Rm,G2)-VolT(Rm,G3))/2e-7
nt=Kst*(Gab-CHI)-(Pe/ds)[:,None]*gh; mm=Jst*Omb
r1,L1=q1[0],q1[1]
for j in (0,2,N):
    fd=np.zeros(3); fs=np.zeros(3)
    for d in range(3):
        qa=[x.copy() for x in q1]; qb=[x.copy() for x in q1]; qa[0][j,d]+=eps; qb[0][j,d]-=eps
        fd[d]=(Umid(qa)-Umid(qb))/(2*eps)
        sg=np.zeros(3); sg[d]=eps
        qa=[x.copy() for x in q1]; qb=[x.copy() for x in q1]; qa[1][j]=qa[1][j]@cay(sg); qb[1][j]=qb[1][j]@cay(-sg)
        fs[d]=(Umid(qa)-Umid(qb))/(2*eps)
    Lh=lambda e: 0.5*(L1[e]+L1[e+1])
    form=np.zeros(3); tor=np.zeros(3)
    if j>0:
        e=j-1; w_=ds*Om1[e]; Gj=L1[j].T@(r1[j+1-1+1-1+0]-r1[j-1])/ds if False else L1[j].T@(r1[j]-r1[j-1])/ds
        form+=0.5*Lh(e)@nt[e]
        tor+=0.5*(dcay_inv(w_)@mm[e]+0.5*ds*np.cross(nt[e],Gj))
    if j<N:
        e=j; w_=ds*Om1[e]; Gj=L1[j].T@(r1[j+1]-r1[j])/ds
        form-=0.5*Lh(e)@nt[e]
        tor+=0.5*(-dcay_inv(-w_)@mm[e]+0.5*ds*np.cross(nt[e],Gj))
    print(j,"dU/dr", fd, form); print(j,"dU/dsig", fs, tor)
